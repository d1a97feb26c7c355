"""HeightNet: the per-pixel height network (LapDepth family), its training, export and evaluation.

Only ``heightnet.predict`` and ``heightnet.metrics`` run without torch (ONNX Runtime); every
other module needs the ``train`` extra.
"""
