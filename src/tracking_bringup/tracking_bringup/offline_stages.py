"""The graph's compute stages run in one process, without ROS, as the graph's nodes run them:
the detector node's CNN and the stereo node's :class:`stereo_depth_node.pipeline.StereoPipeline`
with the graph's parameter file (``pipeline.params.yaml``), ``-p NODE.PARAM:=VALUE`` overrides
on top, their thread counts and malloc policy. Shared by the benchmarks that time a frame's path
outside the graph (``bench/bench_graph.py``'s per-stage baseline, ``bench/bench_side_by_side.py``).
"""

from __future__ import annotations

import dataclasses

from . import graph
from .environment import PARAMS_FILE
from .parameters import default


@dataclasses.dataclass
class GraphStages:
    """The CNN and the stereo node's settings as the graph runs them (threads set)."""

    detector: object  # detector_node's detector (``detect(rgb)`` -> detections)
    detector_threads: int
    stereo_values: dict  # the stereo node's parameter values (file section, then overrides)
    stereo_config: object  # stereo_depth_node.parameters' config of those values

    def pipeline(self, trace=None, **values):
        """A new :class:`StereoPipeline` of the graph's stereo settings (``values``: changed
        ones, e.g. ``map_area="band"``)."""
        from stereo_depth_node.parameters import stereo_config_from_values
        from stereo_depth_node.pipeline import StereoPipeline

        config = (
            stereo_config_from_values({**self.stereo_values, **values})
            if values
            else self.stereo_config
        )
        kwargs = {"trace": trace} if trace is not None else {}
        return StereoPipeline.from_config(config, **kwargs)


def graph_stages(overrides: list[str] = ()) -> GraphStages:
    """Load the CNN and read the stereo node's settings as the graph does (the parameter
    file's sections, then ``overrides``); set torch's and OpenCV's threads to the nodes' counts
    and, as the stereo node does, keep freed memory for reuse."""
    import cv2
    import torch
    from detector_node.loading import load_detector
    from stereo_depth_node.offline import parameter_values
    from stereo_depth_node.parameters import stereo_config_from_values
    from vehicle_common.malloc_policy import keep_freed_memory

    values = dict(graph.file_parameters(PARAMS_FILE).get(graph.STEREO.name, {}))
    values.update(parameter_values(None, graph.node_overrides(overrides, graph.STEREO.name)))
    config = stereo_config_from_values(values)
    det_overrides = graph.node_overrides(overrides, graph.DETECTOR.name)
    det_threads = int(
        graph.parameter_value(PARAMS_FILE, det_overrides, graph.DETECTOR.name, "num_threads")
    )
    torch.set_num_threads(det_threads)
    detector = load_detector("", "cpu")
    cv2.setNumThreads(config.node.num_threads)
    if values.get("keep_freed_memory", default(graph.STEREO.name, "keep_freed_memory")):
        keep_freed_memory()
    return GraphStages(detector, det_threads, values, config)
