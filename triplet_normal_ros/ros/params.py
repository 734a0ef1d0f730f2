"""The node's parameters as plain data plus their validation, so both are testable without rclpy.

The node turns each :class:`ParamSpec` into a ``ParameterDescriptor`` (type, constraints, description, and the inclusive
range of a bounded number, which `ros2 param describe` shows and rqt_reconfigure draws as a slider) and calls
:func:`validate` from its on-set callback; the reason string goes back to whoever tried to set the parameter. rclpy
checks a range first, in its own words ("out of range"); what a range cannot say (radius > 0 but not 0, k 0 or at least
3, a finite number) is said by the parameter's rule. A parameter that is an estimator setting is judged by that
setting's one rule (`core.settings.reason`), the same rule `triplet-normal estimate`, `bag` and `bags` and the estimator
itself apply; each range holds every value its rule accepts, so the range never refuses what the rule would take. The
viewpoint's rule is the message step's (`pipeline.message_settings.viewpoint_reason`), which `bag` shares; the RViz
outputs' rules are beside the code that draws them (`pipeline.visuals`); the rest are the node's alone.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from ..core.config import defaults
from ..core.config.conventions import PCA_DEFAULT_K
from ..core.config.device import device_type
from ..core.config.plan import checkpoints_in_words
from ..core.config.settings import Settings, reason
from ..pipeline.message_settings import MessageSettings, viewpoint_reason
from ..pipeline.visuals import MAX_SEGMENTS, VisualSettings, length_reason, stride_reason

#: Parameters whose change builds a new estimator (loading the checkpoint); the rest apply to the next cloud in place.
RELOAD_PARAMS = frozenset({"method", "checkpoint", "device"})

#: Value of ``k`` that means "the method's default": the checkpoint's k for learned, PCA_DEFAULT_K for pca.
K_METHOD_DEFAULT = defaults.K
#: The parameters that are estimator settings, each judged by its rule in `core.settings`.
SETTING_PARAMS = frozenset(f.name for f in fields(Settings))
#: The rules of the parameters that are no estimator setting, each kept where its value is used.
NODE_RULES = {
    "viewpoint": viewpoint_reason,
    "normals_markers_stride": stride_reason,
    "normals_markers_length": length_reason,
}
#: Any value no rule accepts: asking a rule about it yields the words of what it does accept.
_NOTHING = object()
#: The largest values a ROS parameter can hold (int64, a finite double): the top of a range bounded only below.
INT_MAX = 2**63 - 1
FLOAT_MAX = sys.float_info.max
#: Ranges bounded below only: a number >= 0 (or > 0, which its rule says), an integer >= 0 or >= 1.
NON_NEGATIVE = (0.0, FLOAT_MAX)
NON_NEGATIVE_INT = (0, INT_MAX)
POSITIVE_INT = (1, INT_MAX)


def accepted(name: str) -> str:
    """What parameter `name` accepts, in its rule's own words ('a finite number > 0 (metres)'): the descriptor's
    constraints, which can then never disagree with the rule."""
    why = NODE_RULES[name](_NOTHING) if name in NODE_RULES else reason(name, _NOTHING)
    return (why or "").partition(" must be ")[2].rpartition(", got ")[0]


@dataclass(frozen=True)
class ParamSpec:
    """One declared parameter: ``kind`` is the Python type rclpy infers, ``bounds`` an inclusive (lo, hi) range
    (the descriptor's FloatingPointRange, step 0: any value, or IntegerRange, step 1)."""

    name: str
    kind: type
    default: Any
    description: str
    bounds: tuple[float, float] | None = None
    constraints: str = ""
    read_only: bool = False


SPECS: tuple[ParamSpec, ...] = (
    ParamSpec(
        "method",
        str,
        defaults.METHOD,
        "Normal estimator: 'learned' (triplet network), 'pca', or 'hybrid' (PCA; the network where not flat).",
        None,
        accepted("method"),
    ),
    ParamSpec(
        "checkpoint",
        str,
        defaults.CHECKPOINT,
        "A .safetensors checkpoint for 'learned' and 'hybrid': a path, or a shipped name ('default'; 'lite': 6.5x "
        "fewer FLOPs, k = 64; 'range': 56x fewer, k = 32, for range images); empty means the shipped one for the "
        "device: 'default' on a GPU; on a CPU 'range' for range images, 'lite' for other clouds.",
        None,
        accepted("checkpoint"),
    ),
    ParamSpec(
        "device",
        str,
        defaults.DEVICE,
        "Torch device; 'auto' takes the GPU when torch sees one.",
        None,
        accepted("device"),
    ),
    ParamSpec(
        "batch_size",
        int,
        defaults.BATCH_SIZE,
        "Patches per forward pass of the learned method.",
        POSITIVE_INT,
        accepted("batch_size"),
    ),
    ParamSpec(
        "radius", float, defaults.RADIUS, "Neighbourhood ball radius in metres.", NON_NEGATIVE, accepted("radius")
    ),
    ParamSpec(
        "k",
        int,
        K_METHOD_DEFAULT,
        "learned: points per patch; pca: most neighbours per point (the nearest k inside the radius). "
        f"{K_METHOD_DEFAULT} means the method's default: the checkpoint's k for learned, {PCA_DEFAULT_K} for pca.",
        NON_NEGATIVE_INT,
        f"{K_METHOD_DEFAULT} (the method's default) or {accepted('k')}",
    ),
    ParamSpec(
        "gate",
        float,
        defaults.GATE,
        "hybrid: where the network answers. On an organized range image (the window survey, the default path for "
        "camera and LiDAR frames) where a part of the window sits more than sqrt(gate) standard errors off the "
        "window's plane (a z threshold; 3.16 at 10); on other clouds (pools) where a quadric explains the "
        "neighbourhood better than PCA's plane by more than this F statistic (about 1 on any flat surface). Lower "
        "sends more points to the network.",
        NON_NEGATIVE,
        accepted("gate"),
    ),
    ParamSpec(
        "bend",
        float,
        defaults.BEND,
        "hybrid: ... and where the departure is more than this height, as a fraction of the ball's radius "
        "('radius', grown by 'range_scale'): on a range image the window part's offset from the plane, on other "
        "clouds the quadric's RMS departure from it (mild sensor waviness stays with the plane fit); 0 leaves the "
        "choice to 'gate' alone.",
        NON_NEGATIVE,
        accepted("bend"),
    ),
    ParamSpec(
        "neighbours",
        str,
        defaults.NEIGHBOURS,
        "Neighbour search: 'kdtree'; 'grid' walks an organized cloud's pixel grid on the device (falls back to the "
        "KD-tree for unorganized clouds); 'voxel' finds the KD-tree's neighbours from sorted cell lists on the device; "
        "'window' answers pca and hybrid's survey from integral images of an organized cloud, O(1) per pixel; 'auto' "
        "takes 'window' for hybrid and whole-ball pca on organized clouds, else the grid (organized) or voxel on a GPU "
        "and the KD-tree on a CPU.",
        None,
        accepted("neighbours"),
    ),
    ParamSpec(
        "range_scale",
        float,
        defaults.RANGE_SCALE,
        "The ball grows with range: a point's radius is max(radius, range_scale x its distance from the sensor); 0 "
        "keeps it fixed (depth cameras). A spinning LiDAR's rings part with range, and a fixed ball holds one ring "
        f"(a line: no normal) beyond a few metres; config/lidar.yaml sets {defaults.LIDAR['range_scale']:g}.",
        (0.0, 1.0),
        accepted("range_scale"),
    ),
    ParamSpec(
        "zeros_are_no_returns",
        bool,
        defaults.ZEROS_ARE_NO_RETURNS,
        "Points at exactly (0, 0, 0) are no-returns (how LiDAR drivers store them in organized clouds): never "
        "neighbours, NaN normal and curvature. false treats them as measured points.",
    ),
    ParamSpec("orient", bool, defaults.ORIENT, "Flip normals toward 'viewpoint' (PCL's flipNormalTowardsViewpoint)."),
    ParamSpec(
        "viewpoint",
        list,
        list(defaults.VIEWPOINT),
        "[x, y, z] in the cloud's frame that normals face when 'orient' is true; the origin is the depth sensor.",
        None,
        accepted("viewpoint"),
    ),
    ParamSpec(
        "stats_period",
        float,
        defaults.STATS_PERIOD,
        "Seconds between info-level processing statistics.",
        (0.1, 3600.0),
        "",
        True,
    ),
    ParamSpec(
        "normals_markers",
        bool,
        defaults.NORMALS_MARKERS,
        "Publish 'normals_markers' (visualization_msgs/MarkerArray): one LINE_LIST marker, a segment along the normal "
        "of every n-th point that has one, coloured like the normal map; built only while something subscribes.",
    ),
    ParamSpec(
        "normals_markers_stride",
        int,
        defaults.NORMALS_MARKERS_STRIDE,
        f"Every n-th point with a normal gets a segment (raised where that would give more than {MAX_SEGMENTS:,}); "
        "a prime keeps an organized cloud's picks from lining up in columns.",
        POSITIVE_INT,
        accepted("normals_markers_stride"),
    ),
    ParamSpec(
        "normals_markers_length",
        float,
        defaults.NORMALS_MARKERS_LENGTH,
        "Length of each normal segment in metres.",
        NON_NEGATIVE,
        accepted("normals_markers_length"),
    ),
    ParamSpec(
        "normal_image",
        bool,
        defaults.NORMAL_IMAGE,
        "Publish 'normal_image' (sensor_msgs/Image, rgb8): an organized cloud's normals as the demo's normal map, "
        "holes black; nothing for unorganized clouds; built only while something subscribes.",
    ),
)

SPEC_BY_NAME: dict[str, ParamSpec] = {s.name: s for s in SPECS}


@dataclass(frozen=True)
class NodeSettings:
    """A validated snapshot of every parameter; the worker reads one snapshot per cloud, so updates never tear."""

    method: str = SPEC_BY_NAME["method"].default
    checkpoint: str = SPEC_BY_NAME["checkpoint"].default
    device: str = SPEC_BY_NAME["device"].default
    batch_size: int = SPEC_BY_NAME["batch_size"].default
    radius: float = SPEC_BY_NAME["radius"].default
    k: int = SPEC_BY_NAME["k"].default
    gate: float = SPEC_BY_NAME["gate"].default
    bend: float = SPEC_BY_NAME["bend"].default
    neighbours: str = SPEC_BY_NAME["neighbours"].default
    range_scale: float = SPEC_BY_NAME["range_scale"].default
    zeros_are_no_returns: bool = SPEC_BY_NAME["zeros_are_no_returns"].default
    orient: bool = SPEC_BY_NAME["orient"].default
    viewpoint: tuple[float, float, float] = tuple(SPEC_BY_NAME["viewpoint"].default)
    stats_period: float = SPEC_BY_NAME["stats_period"].default
    normals_markers: bool = SPEC_BY_NAME["normals_markers"].default
    normals_markers_stride: int = SPEC_BY_NAME["normals_markers_stride"].default
    normals_markers_length: float = SPEC_BY_NAME["normals_markers_length"].default
    normal_image: bool = SPEC_BY_NAME["normal_image"].default

    def checkpoint_in_force(self) -> str:
        """The checkpoint the network methods load: the parameter, or for "" the shipped one for the device
        (`plan.checkpoints_in_words`: both, where range images get another one than other clouds, as on a CPU); ''
        for pca. Asks only for the device's type, so it names a GPU's checkpoint on a machine without one too."""
        return checkpoints_in_words(Settings(method=self.method, checkpoint=self.checkpoint), device_type(self.device))

    def estimator_settings(self) -> Settings:
        """The estimator's settings snapshot: k 0 becomes None (the method's own), "" stays the device's checkpoint."""
        return Settings(
            method=self.method, radius=self.radius, k=None if self.k == K_METHOD_DEFAULT else self.k,
            checkpoint=self.checkpoint, device=self.device, batch_size=self.batch_size, gate=self.gate,
            bend=self.bend, neighbours=self.neighbours, range_scale=self.range_scale,
        )  # fmt: skip

    def estimator_args(self) -> dict[str, Any]:
        """Keyword arguments for ``NormalEstimator``: the fields of `estimator_settings`."""
        return asdict(self.estimator_settings())

    def message_settings(self) -> MessageSettings:
        """What one cloud is answered with (`pipeline.messages.answer_message`): the estimator's snapshot, the
        orientation and the no-return rule."""
        return MessageSettings(self.estimator_settings(), self.orient, self.viewpoint, self.zeros_are_no_returns)

    def visual_settings(self) -> VisualSettings:
        """What the RViz outputs draw of each answer (`ros/visuals.py`)."""
        return VisualSettings(
            self.normals_markers, self.normals_markers_stride, self.normals_markers_length, self.normal_image
        )


def _check_type(spec: ParamSpec, value: Any) -> str | None:
    if spec.kind is float and isinstance(value, int) and not isinstance(value, bool):
        return None
    if spec.kind is int and isinstance(value, bool):
        return f"{spec.name} must be an integer, got {value!r}"
    if not isinstance(value, spec.kind):
        return f"{spec.name} must be {spec.kind.__name__}, got {type(value).__name__} {value!r}"
    return None


def _check_bounds(spec: ParamSpec, value: float) -> str | None:
    if spec.bounds is None:
        return None
    lo, hi = spec.bounds
    if not (math.isfinite(value) and lo <= value <= hi):
        return f"{spec.name} must be in [{lo:g}, {hi:g}], got {value!r}"
    return None


def _check_value(name: str, value: Any) -> str | None:
    if name == "k":
        return _check_k(value)
    if name in SETTING_PARAMS:
        return reason(name, value)
    if name in NODE_RULES:
        return NODE_RULES[name](value)
    return None


def _check_k(value: int) -> str | None:
    """k's rule, with the node's 0 for "the method's default" (the estimator's None)."""
    why = reason("k", None if value == K_METHOD_DEFAULT else value)
    return f"{why} ({K_METHOD_DEFAULT} means the method's default)" if why else None


def validate(name: str, value: Any) -> str | None:
    """Why ``value`` is not acceptable for parameter ``name``, or None; unknown names are not ours and pass."""
    spec = SPEC_BY_NAME.get(name)
    if spec is None:
        return None
    if spec.kind is list and not isinstance(value, str):
        try:
            value = list(value)
        except TypeError:
            return f"{name} must be a list, got {value!r}"
    # the rule first: its words say more than the range's, and every range holds all its rule accepts
    return _check_type(spec, value) or _check_value(name, value) or _check_bounds(spec, value)


def validate_all(values: Mapping[str, Any]) -> str | None:
    """The first reason among ``values``, or None when all are acceptable."""
    for name, value in values.items():
        why = validate(name, value)
        if why:
            return why
    return None


def apply(settings: NodeSettings, values: Mapping[str, Any]) -> NodeSettings:
    """A new snapshot with ``values`` (already validated) applied; unknown names are ignored."""
    known: dict[str, Any] = {}
    for name, value in values.items():
        if name not in SPEC_BY_NAME:
            continue
        spec = SPEC_BY_NAME[name]
        if name == "viewpoint":
            value = tuple(float(v) for v in value)
        elif spec.kind is float:
            value = float(value)
        known[name] = value
    return replace(settings, **known)


def needs_reload(values: Mapping[str, Any]) -> bool:
    """Whether applying ``values`` means building a new estimator rather than editing the running one."""
    return not RELOAD_PARAMS.isdisjoint(values)
