"""The repository's scripts as modules, for tests of their functions (scripts/ is not a package)."""

import importlib.util
from types import ModuleType

from m2h_ros.paths import REPO_DIR


def load_script(name: str) -> ModuleType:
    """``scripts/<name>.py`` imported under the name ``<name>_script``."""
    spec = importlib.util.spec_from_file_location(f"{name}_script", REPO_DIR / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
