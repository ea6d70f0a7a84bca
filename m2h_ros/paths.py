"""Where the project keeps generated data (sound library, RIR banks, episodes, checkpoints)."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent


def data_dir() -> Path:
    """Root of generated, cached data: ``$M2H_DATA_DIR`` or ``~/.cache/m2h_ros``."""
    root = os.environ.get("M2H_DATA_DIR")
    return Path(root).expanduser() if root else Path.home() / ".cache" / "m2h_ros"


REPO_DIR = PACKAGE_DIR.parent
# Where scripts write by default: ignored by git, so a rerun never overwrites the committed docs/results/.
RUNS_DIR = REPO_DIR / "runs"


def repo_relative(path: str | os.PathLike) -> str:
    """``path`` relative to the repository root when it lies inside it (stored results must not
    name this machine's folders), else as given."""
    path = Path(path)
    try:
        return path.resolve().relative_to(REPO_DIR).as_posix()
    except ValueError:
        return str(path)


def file_sha256(path: str | os.PathLike) -> str:
    """The first 12 hex digits of a file's sha256: how tables name the model files they ran."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:12]


def file_label(path: str | os.PathLike) -> str:
    """"<repo-relative path> (sha256 <prefix>)": a model file as a table's setup line names it."""
    return f"{repo_relative(path)} (sha256 {file_sha256(path)})"
