"""The plain install runs a video without the extras; a command that needs one says how to get it."""

from __future__ import annotations

import subprocess
import sys

import pytest

from core.errors import MissingExtraError
from core.extras import require

from media import REPO_ROOT

# Runs the CLI with the extras' packages made unimportable (a finder that refuses them), as
# after a plain `pip install -e .`.
WITHOUT_EXTRAS = """
import sys

class Refuse:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("mujoco", "matplotlib", "torch", "onnx"):
            raise ModuleNotFoundError(f"No module named {name!r}")

sys.meta_path.insert(0, Refuse())
from pipeline.cli import main
code = main(sys.argv[1:])
leaked = [m for m in ("mujoco", "matplotlib", "torch", "onnx") if sys.modules.get(m) is not None]
print("imported extras:", leaked, file=sys.stderr)
sys.exit(code)
"""


def without_extras(*args):
    return subprocess.run([sys.executable, "-c", WITHOUT_EXTRAS, *map(str, args)], cwd=REPO_ROOT,
                          capture_output=True, text=True, timeout=120)


def test_require_returns_the_module():
    import json

    assert require("json", "synth", "test") is json


def test_require_names_the_extra_to_install():
    with pytest.raises(MissingExtraError, match=r"x needs no_such_module_h22, .*pip install -e '\.\[synth\]'"):
        require("no_such_module_h22", "synth", "x")


def test_run_needs_no_extra(tmp_path, box_video, tiny_model):
    result = without_extras("run", box_video, "--out", tmp_path / "out", "--no-progress",
                            "--set", f'height.model="{tiny_model}"')
    assert result.returncode == 0, result.stderr
    assert "imported extras: []" in result.stderr
    assert (tmp_path / "out.tracks.csv").is_file()


@pytest.mark.parametrize("command, extra", [
    (["synth", "--sequences", "1"], "synth"),
    (["train"], "train"),
    (["export"], "train"),
])
def test_a_command_without_its_extra_fails_in_one_line(tmp_path, command, extra):
    result = without_extras(*command, "--out", tmp_path / "out")
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    (line,) = [line for line in result.stderr.splitlines() if line.startswith("heightpipe: error:")]
    assert f"pip install -e '.[{extra}]'" in line
