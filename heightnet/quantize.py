"""INT8 static quantisation of an exported height model with ONNX Runtime.

    python -m heightnet.quantize DATA --out MODEL_INT8.onnx [--model MODEL.onnx] [--frames N]

Calibration frames come from a synth dataset (its "train" split: never the held-out scenes the
accuracy is then measured on), preprocessed exactly as the run-time stage does
(``HeightNetModel.preprocess``); a v2 network whose detection head reads motion gets each
frame's frame before as its second input, as at run time (frames after a sequence's first where
it has more than one; a lone frame is its own frame before, as a run's first frame is).
Weights and activations are INT8 (QDQ format, per-channel weights); the heightpipe metadata
(input size, normalisation, units) is copied over, so the result loads wherever the FP32 model
does. Whether to ship it is decided by measurement: the held-out accuracy (`heightpipe eval DATA
--model FP32 --ablation INT8`; for v2, `heightpipe eval-tracks DATA --set height.model=INT8
--set objects.source=network`) and the speed (bench.model_bench / bench.realtime_bench). v2 in
INT8 lost accuracy for little speed (docs/results.md, fortieth session).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np


class SynthCalibration:
    """ONNX Runtime's calibration reader over preprocessed synth frames."""

    def __init__(self, data: Path, model, frames: int):
        from stages.heightnet_model import PREVIOUS_INPUT
        from synth.dataset import list_sequences

        sequences = list_sequences(data, split="train")
        if not sequences:
            raise SystemExit(f"heightpipe: error: no train sequences in {data}")
        self.feeds: list[dict[str, np.ndarray]] = []
        per_sequence = max(1, -(-frames // len(sequences)))
        for sequence in sequences:
            # A motion-reading head sees a change in every frame but a run's first: calibrate on those.
            start = 1 if model.takes_previous and len(sequence) > 1 else 0
            step = max(1, (len(sequence) - start) // per_sequence)
            for index in range(start, len(sequence), step)[:per_sequence]:
                feed = {model.input_name: _prepared(model, sequence, index)}
                if model.takes_previous:
                    feed[PREVIOUS_INPUT] = _prepared(model, sequence, max(0, index - 1))
                self.feeds.append(feed)
        self.feeds = self.feeds[:frames]
        self._next = iter(self.feeds)

    def get_next(self) -> dict[str, np.ndarray] | None:
        return next(self._next, None)

    def rewind(self) -> None:
        self._next = iter(self.feeds)


def _prepared(model, sequence, index: int) -> np.ndarray:
    """Frame ``index`` of a synth sequence as the network takes it."""
    return model.preprocess(np.ascontiguousarray(sequence.frame(index).rgb[..., ::-1]))


def quantize(model_path: Path, data: Path, out: Path, frames: int) -> int:
    """Writes the INT8 model to ``out``; returns the number of calibration frames used."""
    import onnx
    from onnxruntime.quantization import (CalibrationMethod, QuantFormat, QuantType, quantize_static)
    from onnxruntime.quantization.shape_inference import quant_pre_process

    from stages.heightnet_model import HeightNetModel

    model = HeightNetModel(model_path, threads=2)
    reader = SynthCalibration(data, model, frames)
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
    return len(reader.feeds)


def main() -> None:
    from core.errors import HeightpipeError
    from stages.heightnet_model import SHIPPED_MODEL

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path, help="synth dataset (its train split calibrates)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--model", type=Path, default=SHIPPED_MODEL)
    parser.add_argument("--frames", type=int, default=100, help="calibration frames")
    args = parser.parse_args()
    try:
        used = quantize(args.model, args.data, args.out, args.frames)
    except HeightpipeError as exc:   # the project's own errors are one line each
        raise SystemExit(f"heightpipe: error: {exc}") from None
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.1f} MB) from {used} calibration frames")


if __name__ == "__main__":
    main()
