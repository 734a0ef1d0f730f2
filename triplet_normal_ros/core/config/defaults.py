"""Every default, defined once: the estimator (`settings.Settings`), the node's parameters, `triplet-normal
estimate`, `bag` and `bags` start from these, so a cloud gets the same answer from each, and the YAML presets under
config/ are checked against them (the LiDAR preset's values are `LIDAR`).

Pure Python (no torch): the CLI reads them to build `--help`.
"""

from .conventions import DEPTH_RADIUS, HYBRID_BEND, HYBRID_GATE, LIDAR_RADIUS, LIDAR_RANGE_SCALE, RADIUS_FRACTION

#: The estimator the node runs unless told otherwise: PCA everywhere, the network near edges and folds.
METHOD = "hybrid"
#: "" means the shipped checkpoint for the device that runs the network (`shipped_checkpoint`).
CHECKPOINT = ""
#: Which shipped checkpoint CHECKPOINT stands for, by device type: the default where a GPU runs the network; lite on a
#: CPU, where the default's network and plane fits cost about four times lite's, for no less error with `hybrid` on
#: simulated depth frames (docs/RESULTS.md, the `eval-depth` block), so a cloud costs a fraction of the default's time.
SHIPPED_FOR_DEVICE = {"cuda": "default", "cpu": "lite"}
#: ... except on a range image (an organized cloud whose grid is trusted, `plan.make_plan`), by device type: on a CPU
#: the range checkpoint, trained with depth frames, LiDAR scans and fold frames on a quarter of the default's patch,
#: which answers range images in less time than lite, with less error at folds and about lite's on room frames;
#: on the dense, noisy clouds of the validation set its 128-point pool loses to lite's 256 (docs/RESULTS.md, "The
#: range checkpoint"), so every other cloud keeps lite.
SHIPPED_FOR_RANGE_IMAGES = {"cpu": "range"}
DEVICE = "auto"
#: Patches per forward pass; also bounds the cancel latency on a CPU.
BATCH_SIZE = 256
#: Seeds the network's subsample of each pool (a hash of point, neighbour and seed), so answers repeat exactly.
SEED = 0
#: The ball radius in metres: what depth-camera pipelines use, and what training and evaluation score at.
RADIUS = DEPTH_RADIUS
#: 0 means the method's default: the checkpoint's k for the network methods, PCA_DEFAULT_K for pca.
K = 0
GATE = HYBRID_GATE
BEND = HYBRID_BEND
NEIGHBOURS = "auto"
#: The ball keeps its radius at every range: right for depth cameras. config/lidar.yaml grows it with range.
RANGE_SCALE = 0.0
#: A point at exactly (0, 0, 0) is a LiDAR's no-return (Ouster, Velodyne and Hesai drivers store them so in organized
#: clouds): never a neighbour, NaN normal. A sensor never measures its own origin, so this costs a depth camera nothing.
ZEROS_ARE_NO_RETURNS = True
#: Normals face the viewpoint (PCL's flipNormalTowardsViewpoint); the origin of the cloud's frame is the sensor.
ORIENT = True
VIEWPOINT = (0.0, 0.0, 0.0)
#: The node's name, plain or managed: its logger's, its services' namespace, and the section of a parameter file that
#: configures it (``triplet_normal:``, ``/ns/triplet_normal:``; ``/**:`` configures every node).
NODE_NAME = "triplet_normal"
#: Seconds between the node's statistics lines (and its /diagnostics status).
STATS_PERIOD = 5.0
#: The node's RViz outputs are off until asked for: each costs the worker time on every cloud while RViz listens.
NORMALS_MARKERS = False
#: Every n-th point with a normal gets a segment. A prime shares no factor with a sensor's row width (640, 1024,
#: 2048, ...), so in an organized cloud the picks spread over the image instead of lining up in columns.
NORMALS_MARKERS_STRIDE = 23
#: Metres: short enough that neighbouring segments of a depth frame seldom cross, long enough to see their direction.
NORMALS_MARKERS_LENGTH = 0.02
NORMAL_IMAGE = False
#: The settings config/lidar.yaml sets on top of these (a spinning LiDAR: a wider ball that grows with range).
LIDAR = {"radius": LIDAR_RADIUS, "range_scale": LIDAR_RANGE_SCALE}

#: `triplet-normal estimate` answers cloud files (the paper's benchmark clouds, scans in any units) with the network
#: everywhere; sensor streams (the node, `bag`, `bags`) take METHOD.
ESTIMATE_METHOD = "learned"
#: ... and, without --radius, a ball of this fraction of the cloud's bounding-box diagonal: the training radius, since
#: a file's units are unknown.
ESTIMATE_RADIUS_FRACTION = RADIUS_FRACTION


def shipped_checkpoint(device_type: str, range_image: bool = False) -> str:
    """The shipped checkpoint an empty `checkpoint` means on a device of `device_type` ('cpu', 'cuda'), for a range
    image or for any other cloud."""
    if range_image and device_type in SHIPPED_FOR_RANGE_IMAGES:
        return SHIPPED_FOR_RANGE_IMAGES[device_type]
    return SHIPPED_FOR_DEVICE.get(device_type, "default")
