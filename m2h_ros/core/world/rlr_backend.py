"""Binaural RIR bank rows rendered by RLRAudioPropagation (the ray-traced propagation engine behind
SoundSpaces 2.0), in the very layout of ``acoustics.simulate_source``, so every consumer of a bank works
unchanged (``AcousticsConfig.backend = "rlr"``).

Opt-in: the package ``rlr-audio-propagation`` is licensed CC-BY-NC 4.0 (non-commercial use only), so the
default set-up never installs it; ``scripts/setup.sh --with-rlr`` does (and ``scripts/test.sh``, so that
its tests run in CI). Without it, choosing the backend is a ``ConfigError`` naming both.

What the engine is given, the same world as the project's engine:

* Geometry: every reflecting polygon of ``acoustics._effective_faces`` (each wall side facing a room,
  lintels, floors and ceilings; an imported world's surfaces), triangulated, each moved ``FACE_OFFSET``
  into the room it faces. RLR's triangles reflect on both sides with one material, and a wall between two
  rooms has a side in each room's finish: the two sides become a thin slab, each side hit first from its
  own room.
* Materials: one RLR material per distinct per-band absorption (the project's energy absorption at
  125 Hz - 8 kHz with the room's furnishing spread over its faces, as its own engine uses it), scattering
  ``config.scattering`` and, per face, energy transmission ``10 ** (-wall_transmission_db / 20)``: a
  path through a wall crosses its two faces and so loses ``wall_transmission_db``, as in the project.
  Written as RLR's material JSON.
* Head: the project's head (``hrtf.load_head``: KEMAR, a SOFA file or the free-field pair, diffuse-field
  equalised and normalised as for the project's engine), written as a SOFA file at the simulation rate
  and loaded by RLR as the listener's HRTF.
* Sample rate ``config.sample_rate``, IR length ``config.rir_length``, ears and sources at
  ``config.head_height`` on every grid node; a source closer than ``config.min_distance`` to a receiver
  is heard from that distance straight above the ear (RLR's point source at the ear is singular; the
  project's engine takes such a source's direction as straight up too).

Rows: every receiver is 4 listeners, one per heading (turned by a quaternion). Heading h's first E samples
fill early slot h; heading 0's samples E..T fill the late slot (heading independent in the bank's layout;
after ``early_length`` the field is close to diffuse, so which heading gives it matters little).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
import tempfile
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from m2h_ros.core.world.acoustics import (
    BAND_CENTRES,
    N_HEADINGS,
    AcousticsConfig,
    _effective_faces,
    receiver_positions,
)
from m2h_ros.core.world.hrtf import head_identity, load_head
from m2h_ros.errors import ConfigError
from m2h_ros.paths import data_dir

#: Bump whenever a change in this module changes the numbers in an RLR bank (part of the digest).
VERSION = 1
PACKAGE = "rlr-audio-propagation"
INSTALL_HINT = (f"the rlr acoustics backend needs the package {PACKAGE} (RLRAudioPropagation, licensed "
                f"CC-BY-NC 4.0: non-commercial use only), which is opt-in: install it with "
                f"scripts/setup.sh --with-rlr, or choose acoustics backend 'project'")
FACE_OFFSET = 0.005  # m: a face's shift into its room (a wall between two rooms becomes a 1 cm slab)
HRIR_TAPS = 128  # taps of the head's responses handed to RLR (99.9 % of KEMAR's energy at 16 kHz; cost grows with it)
FREQUENCY_BANDS = 8  # RLR's log-spaced simulation bands (4 or 8 recommended; 8 resolves the octaves)


def require() -> Any:
    """The ``rlr_audio_propagation`` module, or a ConfigError naming the install step and the licence."""
    try:
        import rlr_audio_propagation
    except ImportError as err:
        raise ConfigError(INSTALL_HINT) from err
    return rlr_audio_propagation


def available() -> bool:
    try:
        require()
    except ConfigError:
        return False
    return True


def engine_version() -> str:
    """The installed package's version (part of an RLR bank's key)."""
    require()
    return metadata.version(PACKAGE)


@contextlib.contextmanager
def _quiet_stdout():
    """The engine prints progress lines on the process's stdout (file descriptor 1): drop them."""
    import sys

    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


# ----------------------------------------------------------------------------- inputs


def _triangles(corners: np.ndarray) -> np.ndarray:
    """(T, 3) vertex indices of a planar simple polygon (K, 3), by ear clipping in its plane."""
    import mapbox_earcut

    normal = np.cross(np.roll(corners, -1, axis=0), corners).sum(axis=0)
    keep = [axis for axis in range(3) if axis != int(np.argmax(np.abs(normal)))]
    flat = np.ascontiguousarray(corners[:, keep], np.float64)
    return np.asarray(mapbox_earcut.triangulate_float64(flat, np.array([len(flat)], np.uint32))).reshape(-1, 3)


def scene_geometry(scene: Any, config: AcousticsConfig) -> tuple[np.ndarray, dict[str, np.ndarray], list[dict]]:
    """(V, 3) vertices, triangle indices per material category, and RLR's material entries."""
    transmission = 10.0 ** (-config.wall_transmission_db / 20.0)
    vertices, parts, materials, category_of = [], {}, [], {}
    count = 0
    for _, corners, outward, absorption in _effective_faces(scene):
        key = tuple(np.round(absorption, 6))
        if key not in category_of:
            # Fixed width: RLR picks the material whose label is a substring of the category name.
            category = category_of[key] = f"m2hmaterial{len(category_of):05d}"
            materials.append({
                "name": category, "labels": [category],
                "absorption": [v for f, a in zip(BAND_CENTRES, absorption) for v in (float(f), float(a))],
                "scattering": [v for f in BAND_CENTRES for v in (float(f), float(config.scattering))],
                "transmission": [v for f in BAND_CENTRES for v in (float(f), transmission)],
                "damping": [v for f in BAND_CENTRES for v in (float(f), 0.0)],
                "density": 1000.0, "speed": 1500.0,
            })
        corners = np.asarray(corners, np.float64) - FACE_OFFSET * np.asarray(outward, np.float64)
        parts.setdefault(category_of[key], []).append(_triangles(corners) + count)
        vertices.append(corners)
        count += len(corners)
    return np.vstack(vertices), {name: np.vstack(t) for name, t in parts.items()}, materials


def _write_atomic(path: Path, write) -> Path:
    """``write(tmp)`` then a rename: a reader sees the old file or the whole new one."""
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    write(tmp)
    os.replace(tmp, path)
    return path


def head_sofa(config: AcousticsConfig) -> Path:
    """The project's head at the simulation rate as a SOFA file (cached by head and rate)."""
    key = hashlib.sha256(f"{head_identity(config.head)} {config.head} {config.sample_rate} {VERSION}".encode())
    path = data_dir() / "rlr_heads" / f"{key.hexdigest()[:16]}.sofa"
    if path.is_file():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    return _write_atomic(path, functools.partial(_write_head, config=config))


def _write_head(path: Path, *, config: AcousticsConfig) -> None:
    import sofar

    hrtf = load_head(config.head, config.sample_rate)
    hrirs = np.asarray(hrtf.hrirs[..., :HRIR_TAPS], np.float64)
    fade = hrirs.shape[-1] // 4
    hrirs[..., -fade:] *= np.hanning(2 * fade)[fade:]
    x, y, z = hrtf.directions.T
    sofa = sofar.Sofa("SimpleFreeFieldHRIR", verify=False)
    sofa.Data_IR = hrirs
    sofa.Data_SamplingRate = float(config.sample_rate)
    sofa.SourcePosition = np.column_stack([np.degrees(np.arctan2(y, x)), np.degrees(np.arcsin(np.clip(z, -1, 1))),
                                           np.ones(len(x))])
    sofar.write_sofa(str(path), sofa, compression=0)


def heading_quaternion(heading: int) -> list[float]:
    """[w, x, y, z] rotation from RLR's listener frame (x right, y up, z back) to the world's (z up) for
    a head facing ``heading`` * 90 deg counter-clockwise from +x."""
    angle = heading * np.pi / 2
    c, s = np.cos(angle), np.sin(angle)
    rotation = np.array([[s, 0.0, -c], [-c, 0.0, -s], [0.0, 1.0, 0.0]])  # columns: right, up, back
    w = np.sqrt(max(0.0, 1.0 + np.trace(rotation))) / 2
    x = np.copysign(np.sqrt(max(0.0, 1 + rotation[0, 0] - rotation[1, 1] - rotation[2, 2])) / 2,
                    rotation[2, 1] - rotation[1, 2])
    y = np.copysign(np.sqrt(max(0.0, 1 - rotation[0, 0] + rotation[1, 1] - rotation[2, 2])) / 2,
                    rotation[0, 2] - rotation[2, 0])
    z = np.copysign(np.sqrt(max(0.0, 1 - rotation[0, 0] - rotation[1, 1] + rotation[2, 2])) / 2,
                    rotation[1, 0] - rotation[0, 1])
    return [float(w), float(x), float(y), float(z)]


# ----------------------------------------------------------------------------- simulation


def _context(rlr: Any, scene: Any, config: AcousticsConfig, workdir: Path) -> Any:
    settings = rlr.Config()
    settings.sample_rate = float(config.sample_rate)
    settings.max_ir_length = float(config.rir_length)
    settings.thread_count = int(config.rlr_threads)
    settings.indirect_ray_count = int(config.rlr_rays)
    settings.indirect_sh_order = int(config.rlr_sh_order)
    settings.frequency_bands = FREQUENCY_BANDS
    vertices, parts, materials = scene_geometry(scene, config)
    database = workdir / "materials.json"
    database.write_text(json.dumps({"materials": materials}))
    context = rlr.Context(settings)
    context.set_material_database_json(str(database))
    context.add_object()
    context.add_mesh_vertices(vertices.astype(np.float32).ravel().tolist())
    for category, triangles in parts.items():
        context.add_mesh_indices(triangles.astype(np.uint32).ravel().tolist(), 3, category)
    context.finalize_object_mesh(0)
    return context


def render(scene: Any, source: np.ndarray, receivers: np.ndarray, config: AcousticsConfig) -> np.ndarray:
    """(R, 4, 2, T) float32 binaural RIRs at ``receivers`` (R, 3) for the 4 headings of a source at ``source``."""
    rlr = require()
    sofa = str(head_sofa(config))
    n_taps = config.n_taps
    offsets = receivers - source
    near = np.linalg.norm(offsets, axis=1) < config.min_distance
    with tempfile.TemporaryDirectory(prefix="m2h_rlr_") as workdir, _quiet_stdout():
        context = _context(rlr, scene, config, Path(workdir))
        context.add_source()
        context.set_source_position(0, np.asarray(source, np.float64).tolist())
        layout = rlr.ChannelLayout(rlr.ChannelLayoutType.Binaural, 2)
        for r, point in enumerate(receivers):
            for heading in range(N_HEADINGS):
                index = r * N_HEADINGS + heading
                context.add_listener(layout)
                context.set_listener_hrtf(index, sofa)
                context.set_listener_orientation_quaternion(index, heading_quaternion(heading))
                # A source at (or nearly at) the ear: heard from min_distance, straight above it.
                listener = source - [0.0, 0.0, config.min_distance] if near[r] else point
                context.set_listener_position(index, np.asarray(listener, np.float64).tolist())
        context.simulate()
        out = np.zeros((len(receivers), N_HEADINGS, 2, n_taps), np.float32)
        for r in range(len(receivers)):
            for heading in range(N_HEADINGS):
                audio = context.get_listener_source_audio(r * N_HEADINGS + heading, 0)[:, :n_taps]
                out[r, heading, :, : audio.shape[1]] = audio
    return out


def simulate_source(scene: Any, source_node: int, config: AcousticsConfig) -> np.ndarray:
    """(N, row_length) rows of the bank for one source node, as ``acoustics.simulate_source``'s."""
    points = receiver_positions(scene, config)
    if not 0 <= source_node < len(points):
        raise ConfigError(f"source node {source_node} is not a node of scene {scene.scene_id}")
    rirs = render(scene, points[source_node], points, config)
    n_early = config.n_early
    rows = np.zeros((len(points), config.row_length), np.float32)
    rows[:, : N_HEADINGS * 2 * n_early] = rirs[..., :n_early].reshape(len(points), -1)
    late = rirs[:, 0].copy()
    late[..., :n_early] = 0.0
    rows[:, N_HEADINGS * 2 * n_early:] = late.reshape(len(points), -1)
    return rows.astype(config.storage_dtype)
