"""The bus: the only module that imports zenoh.

A ``Bus`` is one zenoh session (a client of the routers in ``MeshSettings.router_endpoints``,
or a router itself) with typed helpers: publish a pydantic message, subscribe with a model
(invalid payloads are logged, counted and dropped; handler exceptions are logged and counted;
nothing ever raises into zenoh), serve and query queryables, declare and watch liveliness tokens.

Late joiners: ``publish(..., latest=True)`` keeps the last payload per key and answers GETs on
that key with it; ``subscribe(..., latest=True)`` issues that GET once after subscribing.
"""

from __future__ import annotations

import atexit
import json
import logging
import threading
import time
import weakref
from collections import defaultdict, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
import zenoh
from pydantic import BaseModel, ValidationError

from lcmesh.mesh import security
from lcmesh.mesh.ratelimit import TokenBuckets, limited_text
from lcmesh.mesh.settings import MeshSettings

log = logging.getLogger("lcmesh.mesh.bus")
M = TypeVar("M", bound=BaseModel)
KEEP_ALIVE_PER_LEASE = 4


class BusError(RuntimeError):
    """The router can not be reached, or a query got no usable answer."""


class QueryError(ValueError):
    """Raised by a queryable handler to answer with an error message (a bad request, not a crash)."""


@dataclass(frozen=True)
class Reply:
    ok: bool
    payload: bytes
    key: str


class Declared:
    """Something declared on the session; ``undeclare()`` is idempotent and never raises.

    The bus keeps a reference until then: zenoh undeclares a token (or subscriber) it garbage-collects.
    """

    def __init__(self, entity, name: str, registry: set | None = None):
        self._entity, self.name, self._registry = entity, name, registry
        if registry is not None:
            registry.add(self)

    def undeclare(self) -> None:
        entity, self._entity = self._entity, None
        if self._registry is not None:
            self._registry.discard(self)
        if entity is not None:
            try:
                entity.undeclare()
            except Exception as exc:  # closed session: nothing left to undeclare
                log.debug("undeclare %s: %s", self.name, exc)


class Counters:
    """Per-key message counts, invalid payloads, rate-limited queries, handler errors and latency (thread-safe)."""

    def __init__(self, latency_window: int = 2000):
        self._lock = threading.Lock()
        self.msgs_in: dict[str, int] = defaultdict(int)
        self.msgs_out: dict[str, int] = defaultdict(int)
        self.invalid: dict[str, int] = defaultdict(int)
        self.rate_limited: dict[str, int] = defaultdict(int)
        self.handler_errors = 0
        self._latency_ms: deque[float] = deque(maxlen=latency_window)

    def count(self, table: dict[str, int], key: str) -> None:
        with self._lock:
            table[key] += 1

    def error(self) -> None:
        with self._lock:
            self.handler_errors += 1

    def latency(self, ms: float) -> None:
        with self._lock:
            self._latency_ms.append(ms)

    def snapshot(self) -> dict:
        with self._lock:
            lat = np.array(self._latency_ms) if self._latency_ms else None
            return {
                "msgs_in": dict(self.msgs_in), "msgs_out": dict(self.msgs_out), "invalid": dict(self.invalid),
                "rate_limited": dict(self.rate_limited), "handler_errors": self.handler_errors,
                "latency_ms_p50": float(np.percentile(lat, 50)) if lat is not None else None,
                "latency_ms_p99": float(np.percentile(lat, 99)) if lat is not None else None,
            }  # fmt: skip


def _base_config(settings: MeshSettings, mode: str) -> zenoh.Config:
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("transport/link/tx/lease", str(settings.lease_ms))
    config.insert_json5("transport/link/tx/keep_alive", str(KEEP_ALIVE_PER_LEASE))
    return config


def _tls(endpoints: list[str]) -> bool:
    return any(endpoint.startswith("tls/") for endpoint in endpoints)


def _endpoint_host(endpoint: str) -> str:
    address = endpoint.split("/", 1)[1].split("#", 1)[0]
    return address.rsplit(":", 1)[0].strip("[]")


def role_of(source: str) -> str:
    """The bus role a session named `source` authenticates as: an agent role (``sensor``, ``sensor-2``) or operator."""
    for candidate in (source, source.split("-", 1)[0]):
        if candidate in security.ROLES:
            return candidate
    return "operator"


def client_config(settings: MeshSettings, role: str = "operator") -> zenoh.Config:
    """A client of the routers in `settings.router_endpoints`, authenticated as `role`; no multicast scouting.

    BusError if the role's password is not there (yet): the router writes the run's secrets on its first start.
    """
    config = _base_config(settings, "client")
    config.insert_json5("connect/endpoints", json.dumps(settings.router_endpoints))
    if settings.bus_auth:
        password = bus_password(settings, role)
        config.insert_json5("transport/auth/usrpwd", json.dumps({"user": role, "password": password}))
    if _tls(settings.router_endpoints):
        ca = security.SecretPaths(settings.secrets_path).client_ca_cert()
        if not ca.exists():
            raise BusError(f"tls/ endpoint but no CA certificate at {ca} (the router creates it on its first start)")
        config.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(str(ca)))
    return config


def bus_password(settings: MeshSettings, role: str) -> str:
    """`role`'s bus password: ``LCMESH_BUS_PASSWORD``, else the file ``LCMESH_BUS_PASSWORD_FILE`` names, else
    ``SECRETS_DIR/{role}/bus.password``; BusError naming where it looked if none is there."""
    if settings.bus_password is not None:
        return settings.bus_password.get_secret_value()
    if settings.bus_password_file is not None:
        try:
            password = settings.bus_password_file.read_text().strip()
        except OSError as exc:
            raise BusError(f"`LCMESH_BUS_PASSWORD_FILE` = {settings.bus_password_file} can not be read: "
                           f"{exc.strerror or exc}") from None  # fmt: skip
        if not password:
            raise BusError(f"`LCMESH_BUS_PASSWORD_FILE` = {settings.bus_password_file} is empty")
        return password
    password = security.read_password(settings.secrets_path, role)
    if password is None:
        missing = security.SecretPaths(settings.secrets_path).password(role)
        raise BusError(f"no bus password for role {role!r}: {missing} is missing (the router creates the run's "
                       "secrets on its first start; or set LCMESH_BUS_PASSWORD_FILE or LCMESH_BUS_PASSWORD)")
    return password


def router_config(settings: MeshSettings) -> zenoh.Config:
    """A router listening on `settings.listen_endpoints`, linked to `settings.router_peers`.

    With ``bus_auth`` (the default) it creates the run's secrets if missing, checks every session's user and
    password and enforces each role's grants (``security.acl_config``); tls/ endpoints get the run's certificate.
    """
    config = _base_config(settings, "router")
    config.insert_json5("listen/endpoints", json.dumps(settings.listen_endpoints))
    if settings.router_peers:
        config.insert_json5("connect/endpoints", json.dumps(settings.router_peers))
    config.insert_json5("scouting/gossip/enabled", "false")
    tls = _tls(settings.listen_endpoints) or _tls(settings.router_peers)
    if not settings.bus_auth:
        wide = [e for e in settings.listen_endpoints if _endpoint_host(e) not in ("127.0.0.1", "localhost", "::1")]
        if wide:
            raise BusError(f"refusing to listen on {', '.join(wide)} without bus authentication; set "
                           "LCMESH_BUS_AUTH=true (the default) or listen on 127.0.0.1 only")  # fmt: skip
        return config
    hosts = security.default_tls_hosts([_endpoint_host(e) for e in settings.listen_endpoints] + settings.bus_tls_hosts)
    paths = security.ensure_secrets(settings.secrets_path, tls_hosts=hosts if tls else ())
    password = security.read_password(settings.secrets_path, security.ROUTER_USER)
    config.insert_json5("transport/auth/usrpwd", json.dumps({
        "user": security.ROUTER_USER, "password": password, "dictionary_file": str(paths.dictionary)}))
    config.insert_json5("id", json.dumps(security.router_zid(password, settings.listen_endpoints[0])))
    peers = [security.router_zid(password, peer) for peer in settings.router_peers]
    config.insert_json5("access_control", json.dumps(security.acl_config(peers)))
    if tls:
        config.insert_json5("transport/link/tls", json.dumps({
            "listen_private_key": str(paths.router_key), "listen_certificate": str(paths.router_cert),
            "root_ca_certificate": str(paths.ca_cert)}))
    return config


_OPEN_BUSES: weakref.WeakSet = weakref.WeakSet()


def _close_open_buses() -> None:
    """Close sessions left open: zenoh's callback threads are not daemons, so an open session blocks exit."""
    for bus in list(_OPEN_BUSES):
        bus.close()


# threading's exit hook runs before the interpreter joins non-daemon threads (atexit runs after: too late)
getattr(threading, "_register_atexit", atexit.register)(_close_open_buses)


class Bus:
    """One zenoh session with typed publish/subscribe/query helpers."""

    def __init__(self, session, site: str, source: str, role: str | None = None):
        self.session, self.site, self.source, self.role = session, site, source, role
        self.counters = Counters()
        self._publishers: dict[str, object] = {}
        self._latest: dict[str, bytes] = {}
        self._latest_served: dict[str, Declared] = {}
        self._lock = threading.Lock()
        self._closed = False
        self.on_error: Callable[[str, BaseException], None] | None = None
        self._declared: set[Declared] = set()
        _OPEN_BUSES.add(self)

    def _report(self, where: str, exc: BaseException) -> None:
        self.counters.error()
        if self.on_error is not None:
            try:
                self.on_error(where, exc)
            except Exception:
                log.exception("error hook failed")

    # --- opening ------------------------------------------------------------------------------
    @classmethod
    def connect(cls, settings: MeshSettings, source: str, *, role: str | None = None,
                timeout_s: float | None = None) -> "Bus":  # fmt: skip
        """A client session as `role` (default: ``role_of(source)``), retrying with backoff for up to `timeout_s`.

        A wrong password or a role the router does not know looks like an unreachable router to zenoh; the
        error after the timeout says both.
        """
        limit = settings.connect_timeout_s if timeout_s is None else timeout_s
        role = role or role_of(source)
        deadline, delay, attempt = time.monotonic() + limit, 0.05, 0
        while True:
            attempt += 1
            try:
                return cls(zenoh.open(client_config(settings, role)), settings.site, source, role)
            except (zenoh.ZError, BusError) as exc:
                if time.monotonic() + delay > deadline:
                    raise BusError(
                        f"could not reach a router at {', '.join(settings.router_endpoints)} after {attempt} "
                        f"attempts in {limit:.0f} s as role {role!r} ({exc}); start one with `lcmesh router` or set "
                        "LCMESH_ROUTER_ENDPOINTS" + ("; with bus authentication on, check that this role's password "
                        f"in {settings.secrets_path} is the router's" if settings.bus_auth else "")
                    ) from exc
                if attempt == 1 or attempt % 10 == 0:
                    log.info("router not reachable yet (%s); retrying", exc)
                time.sleep(delay)
                delay = min(1.0, delay * 2)

    @classmethod
    def open_router(cls, settings: MeshSettings, source: str = "router") -> "Bus":
        """A router-mode session (what `lcmesh router` runs)."""
        try:
            return cls(zenoh.open(router_config(settings)), settings.site, source, security.ROUTER_USER)
        except zenoh.ZError as exc:
            raise BusError(f"could not start a router on {', '.join(settings.listen_endpoints)}: {exc}") from exc

    def short(self, key: str) -> str:
        """`key` without the ``lcmesh/{site}/`` prefix (counter names)."""
        prefix = f"lcmesh/{self.site}/"
        return key[len(prefix):] if key.startswith(prefix) else key

    # --- publish / subscribe ------------------------------------------------------------------
    def publish(self, key: str, msg: BaseModel, *, latest: bool = False, block: bool = False) -> None:
        """Publish `msg` as JSON; with `latest`, also answer GETs on `key` with it.

        `block`: wait for room in a full send queue instead of dropping (for what must not be lost:
        applied actions, alerts, events, config); periodic samples that the next one supersedes drop.
        """
        self.publish_raw(key, msg.model_dump_json().encode(), latest=latest, block=block)

    def publish_raw(self, key: str, payload: bytes, *, latest: bool = False, block: bool = False) -> None:
        if self._closed:
            return
        publisher = self._publishers.get(key)
        if publisher is None:
            with self._lock:
                publisher = self._publishers.get(key)
                if publisher is None:
                    congestion = zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP
                    publisher = self.session.declare_publisher(key, express=True, congestion_control=congestion)
                    self._publishers[key] = publisher
        if latest:
            self._latest[key] = payload
            if key not in self._latest_served:
                self._latest_served[key] = self.serve_raw(key, lambda _payload, k=key: self._latest.get(k))
        try:
            publisher.put(payload)
        except zenoh.ZError as exc:
            log.warning("publish on %s failed: %s", key, exc)
            return
        self.counters.count(self.counters.msgs_out, self.short(key))

    def subscribe(
        self, key: str, model: type[M], handler: Callable[..., None], *, latest: bool = False, keyed: bool = False
    ) -> Declared:
        """Call `handler(model)` for each valid message on `key` (a key expression; wildcards allowed);
        `handler(model, key)` with `keyed`, the key it arrived on (what the router let its sender publish)."""
        name = self.short(key)

        def on_payload(payload: bytes, where: str) -> None:
            self.counters.count(self.counters.msgs_in, name)
            try:
                msg = model.model_validate_json(payload)
            except (ValidationError, ValueError) as exc:
                self.counters.count(self.counters.invalid, name)
                n = self.counters.invalid[name]
                if n <= 10 or n % 1000 == 0:  # a flood of garbage must not flood the log too
                    log.warning("dropped invalid %s #%d on %s: %s", model.__name__, n, where, _first_line(exc))
                return
            t0 = time.perf_counter()
            try:
                handler(msg, where) if keyed else handler(msg)
            except Exception as exc:
                log.exception("handler for %s failed", where)
                self._report(where, exc)
            finally:
                self.counters.latency((time.perf_counter() - t0) * 1e3)

        def on_sample(sample) -> None:
            try:
                on_payload(sample.payload.to_bytes(), str(sample.key_expr))
            except Exception:  # never raise into zenoh
                self.counters.error()
                log.exception("subscriber callback on %s failed", key)

        subscriber = Declared(self.session.declare_subscriber(key, on_sample), key, self._declared)
        if latest:
            for reply in self.query(key, timeout_s=1.0):
                if reply.ok:
                    on_payload(reply.payload, reply.key)
        return subscriber

    # --- queries ------------------------------------------------------------------------------
    def serve(self, key: str, handler: Callable[[bytes | None], BaseModel | None], *,
              limit: TokenBuckets | None = None) -> Declared:  # fmt: skip
        """Answer GETs on `key` with `handler(payload)`'s JSON; QueryError or any failure becomes an error reply.

        With `limit`, a query over its rate is answered with an error that says when to retry (counted in
        ``counters.rate_limited``), and the handler does not run. A queryable on ``.../*`` keeps a bucket per
        last segment asked (the asking role, ``tools/{name}/{role}``), so one role's flood spends its own.
        """

        def raw(payload: bytes | None) -> bytes | None:
            result = handler(payload)
            return None if result is None else result.model_dump_json().encode()

        return self.serve_raw(key, raw, limit=limit)

    def serve_raw(self, key: str, handler: Callable[[bytes | None], bytes | None], *,
                  limit: TokenBuckets | None = None) -> Declared:  # fmt: skip
        name = self.short(key)
        per_asker = key.endswith("/*")

        def on_query(query) -> None:
            try:
                self.counters.count(self.counters.msgs_in, name)
                if limit is not None:
                    bucket = _bucket(name, str(query.key_expr), per_asker)
                    if bucket is None:
                        self.counters.count(self.counters.invalid, name)
                        query.reply_err(f"ask {name[:-1]}<your role>, not {self.short(str(query.key_expr))}".encode())
                        return
                    wait_s = limit.take(bucket)
                    if wait_s > 0:
                        self.counters.count(self.counters.rate_limited, bucket)
                        query.reply_err(limited_text(f"{limit.rate_per_s:g} queries/s for {bucket}", wait_s).encode())
                        return
                payload = query.payload.to_bytes() if query.payload is not None else None
                try:
                    answer = handler(payload)
                except (QueryError, ValidationError, ValueError) as exc:
                    self.counters.count(self.counters.invalid, name)
                    query.reply_err(str(exc).encode())
                    return
                except Exception as exc:
                    log.exception("queryable %s failed", key)
                    self._report(key, exc)
                    query.reply_err(f"internal error in {self.source}: {type(exc).__name__}: {exc}".encode())
                    return
                if answer is not None:
                    query.reply(query.key_expr, answer)
            except Exception:  # never raise into zenoh
                self.counters.error()
                log.exception("query callback on %s failed", key)

        return Declared(self.session.declare_queryable(key, on_query), key, self._declared)

    def query(self, key: str, payload: bytes | str | None = None, *, timeout_s: float = 2.0) -> list[Reply]:
        """All replies to a GET on `key` (errors included, as ``ok=False``)."""
        if isinstance(payload, str):
            payload = payload.encode()
        replies: list[Reply] = []
        try:
            for reply in self.session.get(key, payload=payload, timeout=timeout_s):
                if reply.ok is not None:
                    replies.append(Reply(True, reply.ok.payload.to_bytes(), str(reply.ok.key_expr)))
                else:
                    replies.append(Reply(False, reply.err.payload.to_bytes(), key))
        except zenoh.ZError as exc:
            raise BusError(f"query on {key} failed: {exc}") from exc
        return replies

    def request(self, key: str, model: type[M], payload: BaseModel | bytes | None = None, *,
                timeout_s: float = 2.0) -> M:  # fmt: skip
        """The first valid answer to a GET on `key`; BusError with the error text if there is none."""
        body = payload.model_dump_json().encode() if isinstance(payload, BaseModel) else payload
        errors = []
        for reply in self.query(key, body, timeout_s=timeout_s):
            if not reply.ok:
                errors.append(reply.payload.decode(errors="replace"))
                continue
            try:
                return model.model_validate_json(reply.payload)
            except ValidationError as exc:
                errors.append(f"invalid {model.__name__}: {_first_line(exc)}")
        raise BusError(f"no answer from {key}" + (f": {'; '.join(errors)}" if errors else " (nobody serves it)"))

    # --- liveliness ---------------------------------------------------------------------------
    def declare_token(self, key: str) -> Declared:
        return Declared(self.session.liveliness().declare_token(key), key, self._declared)

    def watch_liveliness(self, key: str, on_change: Callable[[str, bool], None], *, history: bool = True) -> Declared:
        """Call ``on_change(token_key, alive)`` when a token matching `key` appears or goes."""

        def on_sample(sample) -> None:
            try:
                on_change(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)
            except Exception:
                self.counters.error()
                log.exception("liveliness callback on %s failed", key)

        return Declared(self.session.liveliness().declare_subscriber(key, on_sample, history=history), key,
                        self._declared)

    def alive(self, key: str, *, timeout_s: float = 1.0) -> list[str]:
        """Keys of the live tokens matching `key`."""
        found = []
        for reply in self.session.liveliness().get(key, timeout=timeout_s):
            if reply.ok is not None:
                found.append(str(reply.ok.key_expr))
        return found

    def connected(self) -> bool:
        """Whether this session reaches a router now (a client's link may be down while the router restarts)."""
        if self._closed:
            return False
        try:
            return any(True for _ in self.session.info.routers_zid())
        except Exception:  # a closed or broken session
            return False

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for declared in self._latest_served.values():
            declared.undeclare()
        try:
            self.session.close()
        except Exception as exc:
            log.debug("closing the session: %s", exc)


def _bucket(name: str, asked_key: str, per_asker: bool) -> str | None:
    """The token bucket of a query: the queryable's, or on a ``.../*`` queryable the asker's (its last segment).

    Zenoh hands a queryable no authenticated asker (a query's source_info is what the asking session says
    about itself), so the key carries it: the router's ACL lets each role ask only keys ending in its own
    name (``tools/*/{role}``). None when that segment is a wildcard, which no role is granted.
    """
    if not per_asker:
        return name
    asker = asked_key.rsplit("/", 1)[-1]
    if "*" in asker or "$" in asker:
        return None
    return f"{name[:-1]}{asker}"


def _first_line(exc: Exception) -> str:
    text = str(exc).strip().splitlines()
    return " ".join(text[:3]) if text else type(exc).__name__
