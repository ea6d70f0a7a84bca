"""Sound library of the Move2Hear task: speech, music and background clips, heard and unheard."""

from m2h_ros.core.sounds.library import (
    CATEGORIES,
    SPLITS,
    TARGET_CATEGORIES,
    ClipInfo,
    SoundLibrary,
    SoundLibraryConfig,
)

__all__ = ["CATEGORIES", "SPLITS", "TARGET_CATEGORIES", "ClipInfo", "SoundLibrary", "SoundLibraryConfig"]
