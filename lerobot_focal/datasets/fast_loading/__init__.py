"""Faster reading during training, opt-in: `fast_reader` patches LeRobot's dataset reader to gather frames from an
in-memory tensor cache (`tensor_cache`); see docs/data_throughput.md."""
