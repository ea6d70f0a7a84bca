"""Every error the project raises on purpose derives from M2HError, so callers can catch one type."""


class M2HError(Exception):
    """Base class of all m2h_ros errors."""


class ConfigError(M2HError, ValueError):
    """A configuration value (dataclass field, params YAML, CLI option) is invalid."""


class AudioError(M2HError, ValueError):
    """Audio input is unusable: wrong shape, non-finite samples, silence, bad sample rate."""


class CacheError(M2HError):
    """A cached artefact (RIR bank, sound library, episode file) is missing, stale or corrupt."""


class CheckpointError(M2HError):
    """A checkpoint is missing, corrupt, or does not match the model or settings asked for."""


class BagError(M2HError):
    """A rosbag2 directory or MCAP file is missing, corrupt, or holds unexpected types."""


class EpisodeError(M2HError):
    """An episode file or episode specification is invalid."""


class PipelineError(M2HError):
    """The node graph broke its step contract: a node stopped answering, or sent unusable data."""
