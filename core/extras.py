"""Optional dependencies: imported where a command needs them, with a one-line way to install them.

The plain install (``pip install -e .``) runs ``heightpipe run``, ``replay``, ``batch``,
``calibrate`` and ``predict``. Rendering scenes needs MuJoCo (extra ``synth``), training and
exporting the network need PyTorch (extra ``train``), and pictures need matplotlib (both).
"""

from __future__ import annotations

import importlib
from types import ModuleType

from core.errors import MissingExtraError


def require(module: str, extra: str, needed_by: str) -> ModuleType:
    """Import ``module`` or stop with the pip command that installs the extra that has it."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingExtraError(f"{needed_by} needs {module}, which the plain install leaves out: "
                                f"pip install -e '.[{extra}]'") from exc
