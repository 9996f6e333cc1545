"""Who may say what on the bus: per-role credentials, the router's access control, TLS material.

Zenoh's own mechanisms do the work (docs/mesh.md, Security): every session authenticates to the
router with a user and password (``transport/auth/usrpwd``), the user being the agent's role; the
router's ``access_control`` (default deny) then lets each role send only what its job needs, so a
client holding the UI's password can not publish a proposal, a config document or a stats
message for another agent. Endpoints named ``tls/...`` add TLS with a CA and router certificate
generated here.

A run generates the secrets once (``ensure_secrets``: what exists is kept, so a restarted router
or agent finds the same ones), under ``secrets_dir`` with mode 0700 for folders and 0600 for
files. This module does not import zenoh: it writes files and builds the ACL document that
``bus.py`` hands to the router.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import hmac
import ipaddress
import os
import secrets
import socket
from dataclasses import dataclass
from pathlib import Path

ROLES = ("configuration", "sensor", "control", "maintenance", "monitor", "orchestration", "ui", "operator")
"""Agent roles, plus ``operator``: the person at the command line (``lcmesh demo``, tests, benches)."""
ROUTER_USER = "router"  # linked routers (scale-out) authenticate to each other with this user
PASSWORD_BYTES = 24

# zenoh's ACL message kinds
PUT, SUB, QUERY = "put", "declare_subscriber", "query"
SERVE = ("declare_queryable", "reply")
TOKEN, LIVE_READ = "liveliness_token", ("liveliness_query", "declare_liveliness_subscriber")
ALL_MESSAGES = (PUT, "delete", SUB, QUERY, *SERVE, TOKEN, *LIVE_READ)

# keys below lcmesh/<site>/ that any authenticated role may read (subscribe, or GET the latest)
READABLE = ("plant/state", "control/*/applied", "control/*/proposal", "explain/*", "maintenance/alerts",
            "monitor/report", "monitor/stats/*", "events", "config/*")  # fmt: skip


def _role_id(role: str) -> str:
    """Key-expression chunk for the agent ids of `role`: the role name, or it with a suffix (``sensor-2``)."""
    return f"{role}$*"


def _ui_tools() -> list[str]:
    """The data tools the UI agent serves (the Sensor serves the physics tools and the what-ifs)."""
    from lcmesh.mesh.tools.plant_data import DATA_TOOLS, PLANT_TOOLS

    return [name for name, *_ in DATA_TOOLS if name not in PLANT_TOOLS]


def grants(role: str) -> dict[str, tuple[str, ...]]:
    """What `role` may send into the router: {key below lcmesh/<site>/: message kinds}. Reads come on top."""
    own = {
        "events": (PUT,),
        f"monitor/stats/{_role_id(role)}": (PUT,),
        f"alive/{role}/*": (TOKEN,),
    }
    extra: dict[str, dict[str, tuple[str, ...]]] = {
        "sensor": {"plant/state": (PUT, *SERVE), "control/*/applied": (PUT,), "tools/*": SERVE,
                   f"cmd/{_role_id('sensor')}/*": SERVE},
        "control": {"control/*/proposal": (PUT,), "explain/*": (PUT,), "tools/*": (QUERY,)},
        "maintenance": {"maintenance/alerts": (PUT,)},
        "monitor": {"monitor/report": (PUT, *SERVE)},
        "configuration": {"config/*": (PUT, *SERVE), "configure/*/*": SERVE},
        "orchestration": {f"cmd/{_role_id('orchestration')}/*": SERVE, "cmd/*/*": (QUERY,)},
        "ui": {"configure/ui/*": (QUERY,), "cmd/*/*": (QUERY,), "tools/*": (QUERY,),
               **{f"tools/{name}": SERVE for name in _ui_tools()}},  # the assistant's data tools, no others
        "operator": {"configure/operator/*": (QUERY,), "tools/*": (QUERY,)},  # cmd/*: only orchestration and UI
    }
    if role not in extra:
        raise ValueError(f"unknown bus role {role!r}; the roles are {', '.join(ROLES)}")
    out = dict(own)
    for key, kinds in extra[role].items():
        out[key] = tuple(dict.fromkeys(out.get(key, ()) + kinds))
    return out


def router_zid(router_password: str, endpoint: str) -> str:
    """A router's zenoh id, derived from the mesh's router secret and its first listen endpoint.

    A router that links to a peer (scale-out) is not authenticated by that peer's side of the link
    (only the opener sends a password), so the linking router knows the peer by this id: unguessable
    without the secret, and computable from the peer's endpoint as written in ``router_peers``.
    """
    digest = hmac.new(router_password.encode(), endpoint.encode(), hashlib.sha256).hexdigest()
    return "1" + digest[:31]  # 16 bytes, never zero


def acl_config(peer_router_zids: list[str] | tuple[str, ...] = ()) -> dict:
    """The router's ``access_control`` section: default deny; each role's grants, reads for all, egress open.

    Only what a client sends into the router (ingress) is filtered; what the router forwards out
    (egress) follows from what was let in (a put reaches only declared subscribers). Linked routers
    may send anything: those that opened the link authenticate as ``router``, those this router
    linked to are known by id (`peer_router_zids`).
    """
    rules = [
        {"id": "egress", "permission": "allow", "flows": ["egress"], "messages": list(ALL_MESSAGES),
         "key_exprs": ["lcmesh/**"]},
        {"id": "read", "permission": "allow", "flows": ["ingress"], "messages": [SUB, QUERY, *LIVE_READ],
         "key_exprs": [f"lcmesh/*/{key}" for key in READABLE] + ["lcmesh/*/alive/**"]},
        {"id": "router-link", "permission": "allow", "flows": ["ingress"], "messages": list(ALL_MESSAGES),
         "key_exprs": ["lcmesh/**"]},
    ]  # fmt: skip
    subjects = [{"id": ROUTER_USER, "usernames": [ROUTER_USER]}]
    policies = [{"id": "router-link", "rules": ["egress", "router-link"], "subjects": [ROUTER_USER]}]
    if peer_router_zids:
        subjects.append({"id": "peer-routers", "zids": list(peer_router_zids)})
        policies[0]["subjects"].append("peer-routers")
    for role in ROLES:
        by_kinds: dict[tuple[str, ...], list[str]] = {}
        for key, kinds in grants(role).items():
            by_kinds.setdefault(tuple(sorted(kinds)), []).append(f"lcmesh/*/{key}")
        rule_ids = []
        for i, (kinds, keys) in enumerate(sorted(by_kinds.items())):
            rule_ids.append(f"{role}-{i}")
            rules.append({"id": rule_ids[-1], "permission": "allow", "flows": ["ingress"], "messages": list(kinds),
                          "key_exprs": sorted(keys)})  # fmt: skip
        subjects.append({"id": role, "usernames": [role]})
        policies.append({"id": role, "rules": ["egress", "read", *rule_ids], "subjects": [role]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}  # fmt: skip


# --- files ---------------------------------------------------------------------------------------------
def private_dir(path: Path) -> Path:
    """`path` created (with parents) and set to mode 0700."""
    path.mkdir(parents=True, exist_ok=True)
    os.chmod(path, 0o700)
    return path


def write_secret(path: Path, data: bytes | str) -> None:
    """Write `data` to `path` created with mode 0600 (never world-readable, not even for a moment)."""
    if isinstance(data, str):
        data = data.encode()
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.write(fd, data)
    finally:
        os.close(fd)
    os.replace(tmp, path)


@dataclass(frozen=True)
class SecretPaths:
    """Where a run's bus secrets live (``secrets_dir``)."""

    root: Path

    @property
    def dictionary(self) -> Path:
        """The router's user:password list."""
        return self.root / "bus" / "credentials.txt"

    def password(self, user: str) -> Path:
        return self.root / "bus" / f"{user}.password"

    @property
    def ca_cert(self) -> Path:
        return self.root / "tls" / "ca.pem"

    @property
    def ca_key(self) -> Path:
        return self.root / "tls" / "ca.key"

    @property
    def router_cert(self) -> Path:
        return self.root / "tls" / "router.pem"

    @property
    def router_key(self) -> Path:
        return self.root / "tls" / "router.key"


def ensure_secrets(root: Path, *, tls_hosts: list[str] | tuple[str, ...] = ()) -> SecretPaths:
    """The run's secrets under `root`, created where missing (existing ones are kept: restarts find them)."""
    paths = SecretPaths(Path(root))
    private_dir(paths.root)
    private_dir(paths.root / "bus")
    users = (*ROLES, ROUTER_USER)
    for user in users:
        if not paths.password(user).exists():
            write_secret(paths.password(user), secrets.token_urlsafe(PASSWORD_BYTES))
    lines = [f"{user}:{paths.password(user).read_text().strip()}" for user in users]
    text = "\n".join(lines) + "\n"
    if not paths.dictionary.exists() or paths.dictionary.read_text() != text:
        write_secret(paths.dictionary, text)
    if tls_hosts:
        _ensure_tls(paths, list(tls_hosts))
    return paths


def read_password(root: Path, user: str) -> str | None:
    """`user`'s password from the run's secrets, or None if that file is not there (yet)."""
    try:
        text = SecretPaths(Path(root)).password(user).read_text().strip()
    except FileNotFoundError:
        return None
    return text or None


def default_tls_hosts(endpoint_hosts: list[str]) -> list[str]:
    """Names the router certificate is valid for: loopback, this host, and the endpoints' hosts."""
    hosts = ["localhost", "127.0.0.1", "::1", socket.gethostname(), *endpoint_hosts]
    return [h for h in dict.fromkeys(hosts) if h and h not in ("0.0.0.0", "::", "[::]")]


def _ensure_tls(paths: SecretPaths, hosts: list[str]) -> None:
    """A CA and a router certificate for `hosts` (re-issued when a host is missing from it)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    private_dir(paths.root / "tls")
    now = dt.datetime.now(dt.timezone.utc)

    def pem_key(key) -> bytes:
        return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                 serialization.NoEncryption())  # fmt: skip

    if paths.ca_cert.exists() and paths.ca_key.exists():
        ca_cert = x509.load_pem_x509_certificate(paths.ca_cert.read_bytes())
        ca_key = serialization.load_pem_private_key(paths.ca_key.read_bytes(), None)
    else:
        ca_key = ec.generate_private_key(ec.SECP256R1())
        name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "lc-mesh run CA")])
        ca_cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(ca_key.public_key())
                   .serial_number(x509.random_serial_number()).not_valid_before(now - dt.timedelta(minutes=5))
                   .not_valid_after(now + dt.timedelta(days=3650))
                   .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
                   .sign(ca_key, hashes.SHA256()))  # fmt: skip
        write_secret(paths.ca_key, pem_key(ca_key))
        write_secret(paths.ca_cert, ca_cert.public_bytes(serialization.Encoding.PEM))
    if paths.router_cert.exists() and paths.router_key.exists():
        cert = x509.load_pem_x509_certificate(paths.router_cert.read_bytes())
        try:
            san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
            have = {str(v) for v in san.get_values_for_type(x509.DNSName)}
            have |= {str(v) for v in san.get_values_for_type(x509.IPAddress)}
        except x509.ExtensionNotFound:
            have = set()
        if set(hosts) <= have:
            return
    names = []
    for host in hosts:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host.strip("[]"))))
        except ValueError:
            names.append(x509.DNSName(host))
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "lcmesh-router")])
    cert = (x509.CertificateBuilder().subject_name(subject)
            .issuer_name(ca_cert.subject).public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5)).not_valid_after(now + dt.timedelta(days=825))
            .add_extension(x509.SubjectAlternativeName(names), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .sign(ca_key, hashes.SHA256()))  # fmt: skip
    write_secret(paths.router_key, pem_key(key))
    write_secret(paths.router_cert, cert.public_bytes(serialization.Encoding.PEM))
