"""How heights are encoded for training, and undone inside the exported graph.

The paper puts the ground at the lowest value of its height scale (1 of 0-255) so the network
learns ground vs object before it learns how high. We do the same in log space with an offset:

    encoded = log(target + offset)

where ``target`` is either height / camera height (``relative``, scale-free: the run-time stage
multiplies by the configured camera height) or height in metres (``metres``). Ground (target 0)
maps to log(offset), the lowest value, and the scale-invariant log loss of Eigen et al. applies
unchanged. Offsets: 0.01 of the camera height (3.5-9 cm at the paper's cameras) for ``relative``,
0.05 m for ``metres``, so the encoding is near-logarithmic above about a decimetre in both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

TARGETS = ("relative", "metres")
OUTPUT_UNITS = {"relative": "camera_height_fraction", "metres": "metres"}


@dataclass(frozen=True)
class HeightEncoding:
    target: str
    """'relative' (height / camera height) or 'metres'."""

    @property
    def offset(self) -> float:
        return 0.01 if self.target == "relative" else 0.05

    @property
    def ground_value(self) -> float:
        """Encoded value of the ground: the lowest the network should predict."""
        return math.log(self.offset)

    @property
    def output_units(self) -> str:
        return OUTPUT_UNITS[self.target]

    def target_from_metres(self, height_m, camera_height_m):
        """Training target (before the log) from a height in metres; works on arrays and tensors."""
        return height_m / camera_height_m if self.target == "relative" else height_m

    def metres_from_output(self, output, camera_height_m):
        """Decoded network output (relative or metres) back to metres."""
        return output * camera_height_m if self.target == "relative" else output
