"""ONNX Runtime session options shared by the perception models (keypoint network, front/back
classifier)."""

from __future__ import annotations

import onnxruntime as ort

__all__ = ["session_options"]


def session_options(threads: int) -> ort.SessionOptions:
    """ONNX Runtime options for ``threads`` intra-op threads. Extra threads sleep between calls
    instead of spinning: the pipeline runs a call every few milliseconds, and a spinning thread
    burns the core the decoder needs (2 threads, batch 6: 10.9 CPU ms a call not spinning, 16.7
    spinning, for 6.6 and 5.9 ms of wall time; docs/performance.md)."""
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return options
