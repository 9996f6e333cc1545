"""Who may say what on the bus: per-role credentials, the router's access control, TLS material.

Zenoh's own mechanisms do the work (docs/mesh.md, Security): every session authenticates to the
router with a user and password (``transport/auth/usrpwd``), the user being the agent's role; the
router's ``access_control`` (default deny) then lets each role send only what its job needs, so a
client holding the UI's password can not publish a proposal, a config document or a stats
message for another agent. Endpoints named ``tls/...`` add TLS with a CA and router certificate
generated here.

A run generates the secrets once (``ensure_secrets``: what exists is kept, so a restarted router
or agent finds the same ones), one folder per role under ``secrets_dir`` (mode 0700, files 0600),
so a deployment can hand each role its own folder and nothing else:

| path below ``secrets_dir`` | holds | who needs it |
|---|---|---|
| ``{role}/bus.password`` | the role's bus password | that role's processes |
| ``router/credentials.txt``, ``router/bus.password`` | the router's user list (every password), its own | the router |
| ``configuration/config-signing.key`` | the Ed25519 key that signs each config document | the Configuration agent |
| ``ui/api-token``, ``{control,ui}/llm-api-key`` | secrets ``lcmesh demo`` took from its environment | that role |
| ``public/config-signing.pub``, ``public/ca.pem`` | the signature's public key, the TLS CA (mode 0644) | everyone |
| ``tls/`` | the TLS CA's and the router's keys and certificates | the router |

The folder itself is mode 0711: another user may reach a folder handed to it, never list the rest.
This module does not import zenoh: it writes files and builds the ACL document that ``bus.py``
hands to the router.
"""

from __future__ import annotations

import base64
import datetime as dt
import hashlib
import hmac
import ipaddress
import json
import logging
import os
import secrets
import shutil
import socket
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger("lcmesh.mesh.security")

ROLES = ("configuration", "sensor", "control", "maintenance", "monitor", "orchestration", "ui", "operator")
"""Agent roles, plus ``operator``: the person at the command line (``lcmesh demo``, tests, benches)."""
ROUTER_USER = "router"  # linked routers (scale-out) authenticate to each other with this user
PASSWORD_BYTES = 24
PUBLIC = "public"  # the folder every role may read: public keys and the CA certificate
LLM_KEY_ROLES = ("control", "ui")  # the roles that call an LLM endpoint (LCMESH_LLM_API_KEY)
CONFIG_SIGNATURE_CONTEXT = b"lcmesh config document v1\n"  # a signature over a config is never valid for else

# zenoh's ACL message kinds
PUT, SUB, QUERY = "put", "declare_subscriber", "query"
SERVE = ("declare_queryable", "reply")
TOKEN, LIVE_READ = "liveliness_token", ("liveliness_query", "declare_liveliness_subscriber")
ALL_MESSAGES = (PUT, "delete", SUB, QUERY, *SERVE, TOKEN, *LIVE_READ)

# keys below lcmesh/<site>/ that any authenticated role may read (subscribe, or GET the latest)
READABLE = ("plant/state", "control/*/applied", "control/*/proposal", "explain/*", "maintenance/alerts",
            "monitor/report", "monitor/stats/*", "events/*", "events/*/recent", "config/*")  # fmt: skip


def _role_id(role: str) -> str:
    """Key-expression chunk for the agent ids of `role`: the role name, or it with a suffix (``sensor-2``)."""
    return f"{role}$*"


def role_of_agent_id(agent_id: str) -> str | None:
    """The role the router lets publish for `agent_id` (``sensor-2`` -> ``sensor``): the one whose name starts it.

    The inverse of ``_role_id``, unique because no role name starts another. What arrives on
    ``monitor/stats/{agent_id}`` or ``alive/{role}/{agent_id}`` was sent by this role, whatever the message claims.
    """
    return next((role for role in ROLES if agent_id.startswith(role)), None)


def _ui_tools() -> list[str]:
    """The data tools the UI agent serves (the Sensor serves the physics tools and the what-ifs)."""
    from lcmesh.mesh.tools.plant_data import DATA_TOOLS, PLANT_TOOLS

    return [name for name, *_ in DATA_TOOLS if name not in PLANT_TOOLS]


def grants(role: str) -> dict[str, tuple[str, ...]]:
    """What `role` may send into the router: {key below lcmesh/<site>/: message kinds}. Reads come on top."""
    own = {
        f"events/{role}": (PUT,),  # the key names the sender's role: the history's writer relies on it
        f"events/{role}/recent": SERVE,  # its latest events, fetched by the history's writer when it starts
        f"monitor/stats/{_role_id(role)}": (PUT,),
        f"alive/{role}/*": (TOKEN,),
    }
    extra: dict[str, dict[str, tuple[str, ...]]] = {
        "sensor": {"plant/state": (PUT, *SERVE), "control/*/applied": (PUT,), "tools/*/*": SERVE,
                   f"cmd/{_role_id('sensor')}/*": SERVE},
        "control": {"control/*/proposal": (PUT,), "explain/*": (PUT,), "tools/*/control": (QUERY,)},
        "maintenance": {"maintenance/alerts": (PUT,)},
        "monitor": {"monitor/report": (PUT, *SERVE)},
        "configuration": {"config/*": (PUT, *SERVE), "configure/*/*": SERVE},
        "orchestration": {f"cmd/{_role_id('orchestration')}/*": SERVE, "cmd/*/*": (QUERY,)},
        "ui": {"configure/ui/*": (QUERY,), "tools/*/ui": (QUERY,),
               **{f"tools/{name}/*": SERVE for name in _ui_tools()}},  # the assistant's data tools, no others
        "operator": {"configure/operator/*": (QUERY,), "tools/*/operator": (QUERY,)},  # cmd/*: only orchestration
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


def write_secret(path: Path, data: bytes | str, mode: int = 0o600) -> None:
    """Write `data` to `path` atomically, created with `mode` (0600: never world-readable, not even for a moment);
    the mode is set whatever the umask, so a public file (0644) is readable under a strict one too."""
    if isinstance(data, str):
        data = data.encode()
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
    try:
        os.fchmod(fd, mode)
        os.write(fd, data)
    finally:
        os.close(fd)
    os.replace(tmp, path)


def write_public(path: Path, data: bytes) -> None:
    """Write `data` to `path` with mode 0644 (a public key: every role reads it, only its writer writes it)."""
    write_secret(path, data, mode=0o644)


@dataclass(frozen=True)
class SecretPaths:
    """Where a run's secrets live (``secrets_dir``): one folder per role, the router's, and a public one."""

    root: Path

    def role_dir(self, user: str) -> Path:
        """The folder of one bus user's secrets (a role, or ``router``)."""
        return self.root / user

    def password(self, user: str) -> Path:
        return self.role_dir(user) / "bus.password"

    def legacy_password(self, user: str) -> Path:
        """Where a run before per-role folders kept the password (``bus/{user}.password``): still read."""
        return self.root / "bus" / f"{user}.password"

    @property
    def dictionary(self) -> Path:
        """The router's user:password list."""
        return self.role_dir(ROUTER_USER) / "credentials.txt"

    @property
    def public_dir(self) -> Path:
        return self.root / PUBLIC

    @property
    def config_signing_key(self) -> Path:
        """The Configuration agent's Ed25519 private key (PEM)."""
        return self.role_dir("configuration") / "config-signing.key"

    @property
    def config_verify_key(self) -> Path:
        """Its public key (PEM), which every agent checks config documents with."""
        return self.public_dir / "config-signing.pub"

    @property
    def api_token(self) -> Path:
        """The UI's API token, when ``lcmesh demo`` got one in its environment."""
        return self.role_dir("ui") / "api-token"

    def llm_api_key(self, role: str) -> Path:
        """The LLM endpoint's key for `role` (one of ``LLM_KEY_ROLES``), when ``lcmesh demo`` got one."""
        return self.role_dir(role) / "llm-api-key"

    @property
    def ca_cert(self) -> Path:
        return self.root / "tls" / "ca.pem"

    @property
    def public_ca_cert(self) -> Path:
        """A copy of the CA certificate where every role can read it (clients on tls/ endpoints)."""
        return self.public_dir / "ca.pem"

    @property
    def ca_key(self) -> Path:
        return self.root / "tls" / "ca.key"

    @property
    def router_cert(self) -> Path:
        return self.root / "tls" / "router.pem"

    @property
    def router_key(self) -> Path:
        return self.root / "tls" / "router.key"

    def client_ca_cert(self) -> Path:
        """The CA certificate a client checks the router with: the public copy, else ``tls/ca.pem``."""
        return self.public_ca_cert if self.public_ca_cert.exists() else self.ca_cert


def ensure_secrets(root: Path, *, tls_hosts: list[str] | tuple[str, ...] = ()) -> SecretPaths:
    """The run's secrets under `root`, created where missing (existing ones are kept: restarts find them).

    A run from before per-role folders (``bus/*.password``) keeps its passwords: they move into the
    role folders and the shared ``bus/`` folder, which held every one of them, is removed.
    """
    paths = SecretPaths(Path(root))
    paths.root.mkdir(parents=True, exist_ok=True)
    os.chmod(paths.root, 0o711)  # reach a folder handed to you, list none
    users = (*ROLES, ROUTER_USER)
    for user in users:
        private_dir(paths.role_dir(user))
        if not paths.password(user).exists():
            legacy = _read(paths.legacy_password(user))
            write_secret(paths.password(user), legacy or secrets.token_urlsafe(PASSWORD_BYTES))
    lines = [f"{user}:{paths.password(user).read_text().strip()}" for user in users]
    text = "\n".join(lines) + "\n"
    if not paths.dictionary.exists() or paths.dictionary.read_text() != text:
        write_secret(paths.dictionary, text)
    if (paths.root / "bus").is_dir():
        shutil.rmtree(paths.root / "bus")
        log.info("moved the bus passwords from %s into one folder per role", paths.root / "bus")
    paths.public_dir.mkdir(exist_ok=True)
    os.chmod(paths.public_dir, 0o755)
    _ensure_config_signing_key(paths)
    if tls_hosts:
        _ensure_tls(paths, list(tls_hosts))
    if paths.ca_cert.exists() and _read_bytes(paths.public_ca_cert) != paths.ca_cert.read_bytes():
        write_public(paths.public_ca_cert, paths.ca_cert.read_bytes())
    return paths


def _read_bytes(path: Path) -> bytes | None:
    try:
        return path.read_bytes()
    except FileNotFoundError:
        return None


def _read(path: Path) -> str | None:
    """The file's text, stripped; None if it is missing or empty."""
    data = _read_bytes(path)
    return (data.decode().strip() or None) if data is not None else None


def read_password(root: Path, user: str) -> str | None:
    """`user`'s password from its folder in the run's secrets (or a pre-folder run's file), or None if not there."""
    paths = SecretPaths(Path(root))
    return _read(paths.password(user)) or _read(paths.legacy_password(user))


def store_env_secrets(root: Path, environ: dict[str, str]) -> None:
    """Move the secrets `environ` carries for one role into that role's folder (``lcmesh demo``).

    ``LCMESH_API_TOKEN`` becomes ``ui/api-token``, ``LCMESH_LLM_API_KEY`` ``{control,ui}/llm-api-key``; the
    children then get only their own role's files (``processes.agent_env``). A variable no longer set
    removes its file, so a secret taken away is gone at the next start.
    """
    paths = SecretPaths(Path(root))
    targets = {"LCMESH_API_TOKEN": [paths.api_token],
               "LCMESH_LLM_API_KEY": [paths.llm_api_key(role) for role in LLM_KEY_ROLES]}  # fmt: skip
    for name, files in targets.items():
        value = environ.get(name, "").strip()
        for path in files:
            if value:
                private_dir(path.parent)
                write_secret(path, value)
            else:
                path.unlink(missing_ok=True)


# --- config signatures ---------------------------------------------------------------------------------
def config_signed_bytes(version: int, config: dict) -> bytes:
    """What a config document's signature covers: a context, the version and the config as canonical JSON."""
    body = json.dumps(config, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False)
    return CONFIG_SIGNATURE_CONTEXT + f"{int(version)}\n".encode() + body.encode()


class ConfigSigner:
    """The Configuration agent's Ed25519 key: signs each config document it publishes."""

    def __init__(self, pem: bytes):
        from cryptography.hazmat.primitives import serialization
        from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

        key = serialization.load_pem_private_key(pem, None)
        if not isinstance(key, Ed25519PrivateKey):
            raise ValueError("the config signing key must be an Ed25519 private key")
        self._key = key

    def sign(self, version: int, config: dict) -> str:
        """The base64 signature of `version` and `config` (a MeshConfig dumped as JSON-ready data)."""
        return base64.b64encode(self._key.sign(config_signed_bytes(version, config))).decode()


class ConfigVerifier:
    """The Configuration agent's public key: which config documents it signed."""

    def __init__(self, pem: bytes):
        from cryptography.hazmat.primitives import serialization
        from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

        key = serialization.load_pem_public_key(pem)
        if not isinstance(key, Ed25519PublicKey):
            raise ValueError("the config verify key must be an Ed25519 public key")
        self._key = key

    def valid(self, version: int, config: dict, signature: str) -> bool:
        """Whether `signature` is the Configuration agent's over `version` and `config`."""
        from cryptography.exceptions import InvalidSignature

        try:
            self._key.verify(base64.b64decode(signature, validate=True), config_signed_bytes(version, config))
        except (InvalidSignature, ValueError):
            return False
        return True


def load_config_signer(root: Path) -> ConfigSigner | None:
    """The Configuration agent's signing key from its folder, or None if that file is not there."""
    pem = _read_bytes(SecretPaths(Path(root)).config_signing_key)
    return ConfigSigner(pem) if pem else None


def load_config_verifier(root: Path) -> ConfigVerifier | None:
    """The public key config documents are checked with, or None if that file is not there."""
    pem = _read_bytes(SecretPaths(Path(root)).config_verify_key)
    return ConfigVerifier(pem) if pem else None


def _ensure_config_signing_key(paths: SecretPaths) -> None:
    """An Ed25519 key pair for config documents: the private half in configuration/, the public one in public/."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

    if paths.config_signing_key.exists():
        key = serialization.load_pem_private_key(paths.config_signing_key.read_bytes(), None)
    else:
        key = Ed25519PrivateKey.generate()
        write_secret(paths.config_signing_key, key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()))
    public = key.public_key().public_bytes(serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo)
    if _read_bytes(paths.config_verify_key) != public:
        write_public(paths.config_verify_key, public)


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
