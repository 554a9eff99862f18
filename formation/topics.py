"""The Foxglove topics of a run: what the live view serves and a viewer or a layout names.

Zenoh keys (:mod:`formation.keys`) carry the run between processes; these topics carry its
derived views (the scene, the transforms, the metrics, netem's decisions, the log and the
live view's own statistics) to Foxglove, live and in ``formation replay --foxglove``.
"""

SCENE_TOPIC = "/formation/scene"
TF_TOPIC = "/tf"
LOG_TOPIC = "/formation/log"
METRICS_TOPIC = "/formation/metrics"
DECISIONS_TOPIC = "/netem/decisions"
STATS_TOPIC = "/formation/live"  # the live view's own statistics
