"""INT8 static quantisation of an exported height model with ONNX Runtime.

    python -m heightnet.quantize DATA --out MODEL_INT8.onnx [--model MODEL.onnx] [--frames N]

Calibration frames come from a synth dataset (its "train" split: never the held-out scenes the
accuracy is then measured on), preprocessed exactly as the run-time stage does
(``HeightNetModel.preprocess``). Weights and activations are INT8 (QDQ format, per-channel
weights); the heightpipe metadata (input size, normalisation, units) is copied over, so the
result loads wherever the FP32 model does. Whether to ship it is decided by measurement: the
held-out accuracy (`heightpipe eval DATA --model FP32 --ablation INT8`) and the speed
(bench.model_bench / bench.realtime_bench).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np


class SynthCalibration:
    """ONNX Runtime's calibration reader over preprocessed synth frames."""

    def __init__(self, data: Path, model, input_name: str, frames: int):
        from synth.dataset import list_sequences

        sequences = list_sequences(data, split="train")
        if not sequences:
            raise SystemExit(f"heightpipe: error: no train sequences in {data}")
        self.tensors: list[np.ndarray] = []
        per_sequence = max(1, -(-frames // len(sequences)))
        for sequence in sequences:
            step = max(1, len(sequence) // per_sequence)
            for index in range(0, len(sequence), step)[:per_sequence]:
                bgr = np.ascontiguousarray(sequence.frame(index).rgb[..., ::-1])
                self.tensors.append(model.preprocess(bgr))
        self.tensors = self.tensors[:frames]
        self.input_name = input_name
        self._next = iter(self.tensors)

    def get_next(self) -> dict[str, np.ndarray] | None:
        tensor = next(self._next, None)
        return None if tensor is None else {self.input_name: tensor}

    def rewind(self) -> None:
        self._next = iter(self.tensors)


def quantize(model_path: Path, data: Path, out: Path, frames: int) -> int:
    """Writes the INT8 model to ``out``; returns the number of calibration frames used."""
    import onnx
    from onnxruntime.quantization import (CalibrationMethod, QuantFormat, QuantType, quantize_static)
    from onnxruntime.quantization.shape_inference import quant_pre_process

    from stages.heightnet_model import HeightNetModel

    model = HeightNetModel(model_path, threads=2)
    reader = SynthCalibration(data, model, model.input_name, frames)
    with tempfile.TemporaryDirectory() as tmp:
        prepared = Path(tmp) / "prepared.onnx"
        quant_pre_process(str(model.path), str(prepared), skip_symbolic_shape=True)
        quantize_static(str(prepared), str(out), reader, quant_format=QuantFormat.QDQ,
                        per_channel=True, activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
                        calibrate_method=CalibrationMethod.MinMax)
    source = onnx.load(str(model.path), load_external_data=False)
    quantized = onnx.load(str(out))
    present = {entry.key for entry in quantized.metadata_props}
    for entry in source.metadata_props:
        if entry.key not in present:
            quantized.metadata_props.add(key=entry.key, value=entry.value)
    onnx.save(quantized, str(out))
    return len(reader.tensors)


def main() -> None:
    from stages.heightnet_model import SHIPPED_MODEL

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path, help="synth dataset (its train split calibrates)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--model", type=Path, default=SHIPPED_MODEL)
    parser.add_argument("--frames", type=int, default=100, help="calibration frames")
    args = parser.parse_args()
    used = quantize(args.model, args.data, args.out, args.frames)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.1f} MB) from {used} calibration frames")


if __name__ == "__main__":
    main()
