"""One way to open an ONNX file for the run: an ONNX Runtime CPU session, a bad file one clear error.

The height network and the box refiner both open their files here, so both get the same thread
settings and the same one-line error for a file ONNX Runtime cannot load.
"""

from __future__ import annotations

from pathlib import Path

from core.errors import ModelError


def cpu_session(path: str | Path, threads: int, sizes: dict[str, int] | None = None):
    """An ONNX Runtime CPU session with ``threads`` intra-op threads; ``sizes`` fixes the model's
    free dimensions by name."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    # ONNX Runtime's pool threads busy-wait for the next piece of work by default: on two
    # cores the second thread then burns a core the other stages need (sample, 2 threads:
    # 41 ms of CPU per run spinning, 23 ms not, 21 ms with one thread; outputs identical).
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    options.log_severity_level = 3
    for name, size in (sizes or {}).items():
        options.add_free_dimension_override_by_name(name, size)
    try:
        return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own untyped errors for bad files
        first_line = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ModelError(f"{path} is not a loadable ONNX model: {first_line[:200]}") from None
