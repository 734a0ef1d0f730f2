"""Every error class a user can see, in one place, importing nothing of ours.

Each layer raises these; the CLI turns any :class:`TripletNormalError` into one line on stderr, and the node logs it
and keeps serving. Subclassing the builtin that the error used to be (ValueError, RuntimeError) keeps ``except
ValueError`` callers working.
"""


class TripletNormalError(Exception):
    """Base of every expected failure: bad input, settings, files or checkpoints. Never a bug."""


class UsageError(TripletNormalError):
    """Command-line arguments that parse but make no sense together; the CLI exits with status 2."""


class EstimatorError(TripletNormalError, ValueError):
    """Input or settings the estimator cannot work with; the message says which."""


class CheckpointError(TripletNormalError, RuntimeError):
    """A checkpoint that is missing, not safetensors, not one of ours, or made under other conventions."""


class CloudFileError(TripletNormalError, ValueError):
    """A file that cannot be read or written as a point cloud; the message is one line naming the file."""


class CloudFormatError(TripletNormalError, ValueError):
    """A sensor_msgs/PointCloud2 that cannot be read; the message says exactly why."""


class BagError(TripletNormalError, ValueError):
    """A rosbag2 that cannot be read or written as asked: missing, corrupt, without the topic, of another type."""


class TrainingError(TripletNormalError, ValueError):
    """Training settings that cannot work together, or a run directory that cannot be resumed."""


class EstimationCancelled(RuntimeError):
    """`estimate` saw its cancel event set between batches (node shutdown). Not a user error."""
