"""Opening an ONNX file for the run: a bad file is one clear error; a good one runs on the CPU."""

import pytest

from core.errors import ModelError
from stages.box_refinement import SHIPPED_REFINER
from stages.onnx_session import cpu_session


def test_a_file_onnx_runtime_cannot_load_is_one_line_naming_it(tmp_path):
    bad = tmp_path / "broken.onnx"
    bad.write_bytes(b"not a model")
    with pytest.raises(ModelError) as error:
        cpu_session(bad, threads=1)
    message = str(error.value)
    assert message.startswith(f"{bad} is not a loadable ONNX model") and "\n" not in message


def test_a_model_opens_on_the_cpu():
    session = cpu_session(SHIPPED_REFINER, threads=1)
    assert session.get_providers() == ["CPUExecutionProvider"]
    assert {i.name for i in session.get_inputs()} == {"crops", "log_size"}
