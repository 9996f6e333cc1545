"""The Configuration agent: a versioned, validated, persisted configuration behind queryables.

``lcmesh/{site}/config/{name}`` for ``name`` in all, controller, mode, speed_factor, guardrails,
llm: a GET answers the current ``ConfigDoc`` (every section answers the whole document, so a
reader always sees the version). Changes go to ``lcmesh/{site}/configure/{role}/{name}``, a GET
with a ``ConfigUpdate`` payload: ``changes`` is a partial MeshConfig (nested dicts merge); through
a section's key only that section may change. The router lets only the role named in the key
reach it (``ui`` and ``operator``), so the audit's ``changed_by`` starts with that authenticated
role; the update's own ``by`` (who the UI vouches for) follows it. The new version is validated
(pydantic, the controller registry, the guardrails against the plant), written to the store file atomically
with the diff (``ConfigDoc.changes``: the Sensor records it in history's ``config_changes``), signed
with the Configuration agent's Ed25519 key
(``SECRETS_DIR/configuration/config-signing.key``: agents adopt only a document whose signature
verifies, ``Agent._unsigned``) and published on ``config/all``. Errors name the field and what
would be valid.
"""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Collection
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from lcmesh.mesh import keys
from lcmesh.mesh.agents.base import Agent, default_config
from lcmesh.mesh.bus import QueryError
from lcmesh.mesh.history import HistoryReader
from lcmesh.mesh.security import ConfigSigner, SecretPaths, load_config_signer
from lcmesh.mesh.security import write_secret as write_private
from lcmesh.mesh.messages import CONFIG_SECTIONS, ConfigDoc, ConfigUpdate, MeshConfig
from lcmesh.mesh.tools.guardrails import check_action
from lcmesh.twin.system import SystemDescription, load_system

log = logging.getLogger("lcmesh.mesh.agents.configuration")


def format_errors(exc: ValidationError, prefix: str = "") -> str:
    """One line per problem, each naming its field; unknown fields suggest the closest valid one."""
    lines = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err["loc"])
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            msg = "is not a configuration field"
        elif "input" in err and not isinstance(err["input"], (dict, list)):
            msg += f" (got {err['input']!r})"
        lines.append(f"`{prefix}{loc}` {msg}" if loc else msg)
    return "; ".join(lines)


def _merge(base: dict, changes: dict) -> dict:
    merged = dict(base)
    for key, value in changes.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _merge(merged[key], value)
        else:
            merged[key] = value
    return merged


def _diff(old: Any, new: Any, path: str = "") -> dict[str, list]:
    if isinstance(old, dict) and isinstance(new, dict):
        out: dict[str, list] = {}
        for key in sorted(set(old) | set(new)):
            out.update(_diff(old.get(key), new.get(key), f"{path}{key}."))
        return out
    return {} if old == new else {path.rstrip("."): [old, new]}


class ConfigStore:
    """The configuration's versions: validation, persistence, audit."""

    def __init__(self, path: Path, seed: MeshConfig, system: SystemDescription | None, history_path: Path | None,
                 controller_plugins: Collection[str] = (), signer: ConfigSigner | None = None):  # fmt: skip
        self.path, self.system, self.history_path = Path(path), system, history_path  # history: read only
        self.controller_plugins = tuple(controller_plugins)  # third-party controllers the mesh may load
        self.signer = signer  # None: documents go out unsigned (a mesh without bus authentication)
        self._lock = threading.Lock()
        if self.path.exists():
            self.doc = self._signed(ConfigDoc.model_validate_json(self.path.read_text()))
            self._check_against_history()
        else:
            seeded = ConfigDoc(source="configuration", version=1, config=self.validate(seed.model_dump()),
                               changed_by="settings", reason="initial configuration from LCMESH_* settings")
            self.doc = self._signed(seeded)
            self._check_against_history(new=True)

    def _signed(self, doc: ConfigDoc) -> ConfigDoc:
        if self.signer is None:
            return doc
        return doc.model_copy(update={"signature": self.signer.sign(doc.version, doc.config.model_dump(mode="json"))})

    def _check_against_history(self, new: bool = False) -> None:
        """Versions never go back and never jump; the content is this agent's own store's, never history's.

        History is written by another agent (the Sensor) and its rows carry no signature, so a version
        there newer than the store (or the same with other content) is not adopted: the store's content
        is issued again after it, signed and audited. A `new` store (none on disk yet) is persisted here.
        """
        rows = []
        if self.history_path is not None and Path(self.history_path).exists():
            reader = HistoryReader(self.history_path)
            try:
                rows = reader.config_changes(limit=1)
            finally:
                reader.close()
        ours = self.doc.config.model_dump(mode="json")
        if rows and (rows[0]["version"] > self.doc.version or
                     (rows[0]["version"] == self.doc.version and rows[0]["config"] != ours)):  # fmt: skip
            audited = int(rows[0]["version"])
            log.warning("history's latest audited version %d is not the one %s holds (version %d); issuing the "
                        "store's content as version %d", audited, self.path, self.doc.version, audited + 1)  # fmt: skip
            self.doc = self._signed(ConfigDoc(source="configuration", version=audited + 1, config=self.doc.config,
                                              changed_by="configuration", reason=f"the content of {self.path}, "
                                              f"issued after history's version {audited}, which it does not hold"))
            self.doc = self._persist(self.doc, {"*": [None, f"re-issued from {self.path}"]})
        elif new:
            self.doc = self._persist(self.doc, {"*": [None, "initial"]})

    def validate(self, data: dict) -> MeshConfig:
        """A MeshConfig from `data`, checked against the controller registry (and allowed plugins) and the plant."""
        from lcmesh.twin.controllers import mesh_refusal

        try:
            config = MeshConfig.model_validate(data)
        except ValidationError as exc:
            raise QueryError(format_errors(exc)) from None
        problem = mesh_refusal(config.controller, self.controller_plugins)
        if problem is not None:
            raise QueryError(f"`controller` {problem}")
        if config.mode == "manual" and config.manual_action is None:
            raise QueryError("`mode` 'manual' needs `manual_action` (setpoints for every cabinet and tower)")
        if self.system is not None:
            try:
                config.guardrails.check_system(self.system)
            except ValueError as exc:
                raise QueryError(f"`guardrails`: {exc}") from None
            if config.manual_action is not None:
                problem = check_action(config.manual_action.to_action(), self.system)
                if problem:
                    raise QueryError(f"`manual_action`: {problem}")
        return config

    def apply(self, update: ConfigUpdate, section: str, role: str = "operator") -> tuple[ConfigDoc, dict]:
        """A new version from `update` through the `section` key, asked by the bus identity `role`."""
        if section != "all":
            others = sorted(set(update.changes) - {section})
            if others:
                raise QueryError(f"through config/{section} only `{section}` may change, not {others}; "
                                 "use config/all for several sections")  # fmt: skip
        with self._lock:
            current = self.doc
            if update.expected_version is not None and update.expected_version != current.version:
                raise QueryError(f"`expected_version` is {update.expected_version} but the current version is "
                                 f"{current.version}; re-read and retry")  # fmt: skip
            old = current.config.model_dump(mode="json")
            config = self.validate(_merge(old, update.changes))
            changes = _diff(old, config.model_dump(mode="json"))
            if not changes:
                return current, {}
            doc = self._signed(ConfigDoc(source="configuration", version=current.version + 1, config=config,
                                         changed_by=f"{role}/{update.by}", reason=update.reason))  # fmt: skip
            doc = self._persist(doc, changes)
            self.doc = doc
        return doc, changes

    def _persist(self, doc: ConfigDoc, changes: dict) -> ConfigDoc:
        """`doc` carrying `changes`, written to the store file; the Sensor audits it in history from ``config/all``."""
        doc = doc.model_copy(update={"changes": changes})
        self.path.parent.mkdir(parents=True, exist_ok=True)
        write_private(self.path, doc.model_dump_json(indent=2))
        return doc


class ConfigurationAgent(Agent):
    role = "configuration"

    def __init__(self, settings, agent_id: str | None = None):
        super().__init__(settings, agent_id)
        self.store: ConfigStore | None = None
        self.tally = {"changes": 0, "refused": 0}

    def on_start(self) -> None:
        s = self.settings
        try:
            system = load_system(s.system)
        except Exception as exc:  # the store still works; plant-specific checks are skipped
            log.warning("system %r does not load (%s); guardrails are not checked against a plant", s.system, exc)
            system = None
        path = s.configuration.store_path or s.data_dir / "config.json"
        signer = load_config_signer(s.secrets_path)
        if signer is None and s.bus_auth:
            raise RuntimeError(f"no config signing key at {SecretPaths(s.secrets_path).config_signing_key}: the "
                               "router creates it with the run's secrets; without it no agent adopts a configuration")
        self.store = ConfigStore(path, default_config(s), system, s.history_file, s.allowed_controller_plugins, signer)
        log.info("configuration version %d from %s", self.store.doc.version, path)
        for name in CONFIG_SECTIONS:
            self.serve(keys.config(self.site, name), lambda payload, name=name: self._read(name, payload))
            for role in keys.CONFIGURING_ROLES:
                self.serve(keys.configure(self.site, role, name),
                           lambda payload, name=name, role=role: self._query(name, payload, role))
        self.bus.publish(keys.config(self.site, "all"), self.store.doc, block=True)

    def details(self) -> dict:
        return {"version": self.store.doc.version if self.store else None, **self.tally}

    def _read(self, section: str, payload: bytes | None) -> ConfigDoc:
        if payload:
            self.tally["refused"] += 1
            raise QueryError(f"config/{section} only answers the current document; changes go to "
                             f"configure/<role>/{section} (roles {', '.join(keys.CONFIGURING_ROLES)})")  # fmt: skip
        return self.store.doc

    def _query(self, section: str, payload: bytes | None, role: str) -> ConfigDoc:
        if not payload:
            return self.store.doc
        try:
            update = ConfigUpdate.model_validate_json(payload)
        except ValidationError as exc:
            self.tally["refused"] += 1
            raise QueryError(f"invalid ConfigUpdate: {format_errors(exc)}") from None
        except ValueError as exc:
            self.tally["refused"] += 1
            raise QueryError(f"the request is not JSON: {exc}") from None
        try:
            doc, changes = self.store.apply(update, section, role if self.settings.bus_auth else f"{role}?")
        except QueryError:
            self.tally["refused"] += 1
            raise
        if changes:
            self.tally["changes"] += 1
            log.info("config version %d by %s: %s", doc.version, doc.changed_by, json.dumps(changes, default=str))
            self.bus.publish(keys.config(self.site, "all"), doc, block=True)
        return doc
