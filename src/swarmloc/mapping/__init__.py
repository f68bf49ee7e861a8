"""Line maps: line extraction per scan (:mod:`.lines`), lines carried into the world frame with a robot's belief
(:mod:`.transform`; a scan's world lines: :mod:`.observe`), their fusion into one map (:class:`LineMap`,
:mod:`.linemap`) and the map's error against the true walls (:mod:`.metrics`)."""

from swarmloc.mapping.linemap import LineMap, LineObservation, MapLine
from swarmloc.mapping.lines import LineFit, extract_lines, fit_line, split_and_merge
from swarmloc.mapping.metrics import map_error
from swarmloc.mapping.observe import ScanSeries, scan_observations
from swarmloc.mapping.transform import line_to_world

__all__ = [
    "LineFit",
    "LineMap",
    "LineObservation",
    "MapLine",
    "ScanSeries",
    "extract_lines",
    "fit_line",
    "line_to_world",
    "map_error",
    "scan_observations",
    "split_and_merge",
]
