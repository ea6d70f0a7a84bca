"""Binaural room impulse responses of a scene: image sources + ray-traced tail + a head's HRTF (measured
KEMAR by default; any SOFA head or a free-field microphone pair: ``AcousticsConfig.head``, ``hrtf.load_head``).

Method (per source node, all receiver nodes at once):

* Geometry: every scene wall becomes one pyroomacoustics ``libroom`` polygon per room side it faces
  (libroom walls reflect on one side only, the one their outward normal points away from); doors
  are the gaps between wall polygons, lintels are their own polygons; floor and ceiling are one
  rectangle per maximal cell rectangle of each room. Materials are pyroomacoustics' database
  entries (energy absorption per octave band 125 Hz - 8 kHz); each side of a wall has the wall
  finish of the room it faces.
* Furnishing (``furnishing_area``): a room's furnishing (scene.FURNISHINGS: upholstery, curtains,
  cabinets per m^2 of floor) and its furniture boxes are an equivalent absorption area, spread
  evenly over the room's faces (``_effective_faces``); they add no geometry. ``room_rt60`` (Eyring,
  with air absorption) uses the very same faces, and ``measured_room_rt60`` checks the simulated
  decay against it.
* Early part (heading dependent): libroom's image-source model up to ``ism_max_order`` with
  visibility tested per receiver across the whole non-convex floor plan, so sound reaches other
  rooms through door gaps. Each visible image contributes the KEMAR HRIR of its arrival direction
  in the head frame (nearest of 710 directions), delayed by distance / c (fractional delay in the
  frequency domain), scaled by 1/distance and by its per-band wall reflection (and air) attenuation.
  A direct path that is blocked by walls still passes through them, attenuated by
  ``wall_transmission_db`` per wall crossed.
* Late part (heading independent, diffuse): libroom's ray tracer in hybrid mode (specular rays
  count only after ``ism_max_order`` reflections, so nothing is counted twice; a ``scattering``
  share of every reflection goes diffuse, which makes the decay follow Eyring instead of lingering
  in grazing specular orbits between parallel walls) gives per-band
  energy histograms per receiver; they shape two noise sequences per receiver, mixed per band to
  the diffuse-field interaural coherence sin(kd)/(kd) of ears d apart (the head's ear spacing where it
  defines one, else ``head_width``).

Amplitude convention: the direct path at distance d has amplitude 1/d (times the HRIR, normalised
to unit diffuse-field energy per ear); the ray tracer's histograms use the same energy scale
(checked: direct-path energy 1/d^2).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from importlib.metadata import version
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import fft as sfft

from m2h_ros.core.world.hrtf import KEMAR, Hrtf, head_identity, load_head, parse_head
from m2h_ros.core.world.scene import FURNISHINGS
from m2h_ros.errors import ConfigError

if TYPE_CHECKING:  # imported where banks are built (most processes only read them)
    from pyroomacoustics import libroom

#: Bump whenever a change in this module changes the numbers in a bank (invalidates caches).
VERSION = 2
N_HEADINGS = 4
#: Octave-band centres used for absorption, air absorption and the tail (Hz).
BAND_CENTRES = np.array([125.0, 250.0, 500.0, 1000.0, 2000.0, 4000.0, 8000.0])
_STORAGE_DTYPES = ("float16", "float32")
#: RIR engines behind simulate_source: this module's, or RLRAudioPropagation (rlr_backend, opt-in).
BACKENDS = ("project", "rlr")
BACKEND_HELP = ("the engine of the RIR banks: project (default) or rlr (RLRAudioPropagation; opt-in, licensed "
                "CC-BY-NC 4.0 for non-commercial use: scripts/setup.sh --with-rlr)")
_MAX_ABSORPTION = 0.95  # a face absorbing more would be an open window, not a furnished wall


@dataclass(frozen=True)
class AcousticsConfig:
    """Every setting that changes the impulse responses (all of it keys the on-disk cache)."""

    sample_rate: int = 16000
    # s: total length T of every binaural RIR; at least every default room's longest band RT60
    # (125 Hz - 4 kHz), so tails are not cut off (test_room_acoustics checks it).
    rir_length: float = 1.0
    early_length: float = 0.1  # s: window E of the heading-dependent image-source part
    ism_max_order: int = 3  # image-source reflection order (cost grows ~ walls ** order)
    tail: bool = True  # ray-traced late reverberation
    n_rays: int = 1000
    scattering: float = 0.3  # diffuse share of every reflection (furniture and clutter scatter)
    receiver_radius: float = 0.5  # m: ray-tracing receiver sphere
    hist_bin: float = 0.004  # s: ray-tracing energy histogram resolution
    wall_transmission_db: float = 40.0  # dB lost per wall crossed by a blocked direct path
    air_absorption: bool = True
    head_height: float = 1.5  # m: ears and sources
    head_width: float = 0.18  # m: the diffuse tail's interaural coherence, for heads without an ear spacing
    min_distance: float = 0.5  # m: closer sources are treated as at this distance
    speed_of_sound: float = 343.0  # m/s
    storage_dtype: str = "float32"  # float16 halves the disk size, but casting triples gather time
    seed: int = 0  # noise of the late tail
    # kemar | sofa:PATH | free_field:SPACING_M (hrtf.load_head); a SOFA head is keyed by its content
    head: str = KEMAR
    # project (this module's engine) | rlr (RLRAudioPropagation, opt-in, CC-BY-NC 4.0: rlr_backend)
    backend: str = "project"
    rlr_rays: int = 2000  # rlr backend: indirect rays traced from every listener (quality and cost)
    rlr_threads: int = 1  # rlr backend: CPU threads of its simulation (speed only: not in the digest)
    # rlr backend: spherical-harmonic order of its indirect field (everything but an unoccluded direct path:
    # reflections, diffraction, transmission). Order 1 (RLR's default) carries no interaural delay.
    rlr_sh_order: int = 1

    def __post_init__(self) -> None:
        positive = (
            "sample_rate", "rir_length", "early_length", "n_rays", "receiver_radius", "hist_bin",
            "head_height", "head_width", "min_distance", "speed_of_sound",
        )
        for name in positive:
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not value > 0:
                raise ConfigError(f"AcousticsConfig.{name} must be a positive number, got {value!r}")
        for name in ("sample_rate", "n_rays", "ism_max_order", "seed"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool):
                raise ConfigError(f"AcousticsConfig.{name} must be an integer, got {value!r}")
        if not 0 <= self.scattering <= 1:
            raise ConfigError(f"AcousticsConfig.scattering must be in [0, 1], got {self.scattering!r}")
        if not 0 <= self.ism_max_order <= 6:
            raise ConfigError(f"AcousticsConfig.ism_max_order must be in 0..6, got {self.ism_max_order}")
        if not 0 <= self.wall_transmission_db:
            raise ConfigError(
                f"AcousticsConfig.wall_transmission_db must be >= 0 (inf: opaque walls), "
                f"got {self.wall_transmission_db!r}"
            )
        if self.early_length > self.rir_length:
            raise ConfigError(
                f"AcousticsConfig.early_length ({self.early_length}) must not exceed "
                f"rir_length ({self.rir_length})"
            )
        if self.storage_dtype not in _STORAGE_DTYPES:
            raise ConfigError(
                f"AcousticsConfig.storage_dtype must be one of {_STORAGE_DTYPES}, got {self.storage_dtype!r}"
            )
        if not isinstance(self.tail, bool) or not isinstance(self.air_absorption, bool):
            raise ConfigError("AcousticsConfig.tail and .air_absorption must be booleans")
        parse_head(self.head)
        if self.backend not in BACKENDS:
            raise ConfigError(f"AcousticsConfig.backend must be one of {BACKENDS}, got {self.backend!r}")
        if self.backend == "rlr":
            from m2h_ros.core.world import rlr_backend

            rlr_backend.require()  # not installed: an error naming the opt-in install step and the licence
        for name in ("rlr_rays", "rlr_threads", "rlr_sh_order"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 1:
                raise ConfigError(f"AcousticsConfig.{name} must be a positive integer, got {value!r}")

    @property
    def n_taps(self) -> int:
        return int(round(self.rir_length * self.sample_rate))

    @property
    def n_early(self) -> int:
        return int(round(self.early_length * self.sample_rate))

    @property
    def row_length(self) -> int:
        """Samples stored per (source, receiver): 4 headings x 2 ears x E, then 2 ears x T."""
        return N_HEADINGS * 2 * self.n_early + 2 * self.n_taps

    def digest(self) -> str:
        """Short hash of everything that changes results: settings, code version, libraries, the head
        (KEMAR's banks keep the digest they had before other heads existed), the backend (the
        project's banks keep the digest they had before other backends existed; another backend adds
        its name, settings and version, so the banks of two engines never share a folder)."""
        config = asdict(self)
        identity = head_identity(config.pop("head"))
        hrtf = "MIT_KEMAR_normal_pinna" if identity is None else identity
        backend, rays, sh_order = config.pop("backend"), config.pop("rlr_rays"), config.pop("rlr_sh_order")
        del config["rlr_threads"]  # how fast, not what
        key = {"config": config, "version": VERSION, "pyroomacoustics": version("pyroomacoustics"),
               "hrtf": f"{hrtf}, diffuse-field equalised"}
        if backend != "project":
            from m2h_ros.core.world import rlr_backend  # the opt-in package: a clear error where it is missing

            key["backend"] = {"name": backend, "rays": rays, "engine": rlr_backend.engine_version(),
                              "adapter": rlr_backend.VERSION}
            if sh_order != 1:  # keyed where set, so the banks of RLR's default order keep their digest
                key["backend"]["sh_order"] = sh_order
        payload = json.dumps(key, sort_keys=True)
        return hashlib.sha256(payload.encode()).hexdigest()[:16]


# ----------------------------------------------------------------------------- geometry


def _material_absorption(name: str) -> np.ndarray:
    """Energy absorption of a pyroomacoustics database material at BAND_CENTRES."""
    import pyroomacoustics as pra  # imported where banks are built: most processes only read them

    try:
        material = pra.Material(name)
    except (KeyError, ValueError, TypeError) as err:
        raise ConfigError(f"unknown acoustic material {name!r} (not in pyroomacoustics' database)") from err
    coeffs = np.asarray(material.absorption_coeffs, dtype=np.float64)
    centres = np.asarray(material.energy_absorption.get("center_freqs") or BAND_CENTRES[: coeffs.size])
    if coeffs.size == 1:
        return np.full(BAND_CENTRES.size, coeffs[0])
    return np.interp(np.log2(BAND_CENTRES), np.log2(centres), coeffs)


def _polygon(corners: np.ndarray, outward: np.ndarray, absorption: np.ndarray,
             scattering: float) -> libroom.Wall:
    """A libroom wall from (K, 3) planar corners whose normal points along ``outward`` (away from the room)."""
    from pyroomacoustics import libroom

    if float(np.dot(_newell_normal(corners), outward)) < 0:
        corners = corners[::-1]  # libroom's normal follows the right-hand rule of the corner order
    return libroom.Wall(corners.T.astype(np.float32), absorption.astype(np.float32),
                        np.full(BAND_CENTRES.size, scattering, np.float32))


def _cell_rectangles(cells: tuple[tuple[int, int], ...]) -> list[tuple[int, int, int, int]]:
    """Cover a set of unit cells with few rectangles (x0, y0, x1, y1): row runs merged upwards."""
    rows: dict[int, list[int]] = {}
    for ix, iy in cells:
        rows.setdefault(int(iy), []).append(int(ix))
    runs: list[tuple[int, int, int]] = []  # (x0, x1, y)
    for iy, xs in sorted(rows.items()):
        xs.sort()
        start = prev = xs[0]
        for x in xs[1:] + [None]:
            if x is None or x != prev + 1:
                runs.append((start, prev + 1, iy))
                start = x
            prev = x if x is not None else prev
    rects: list[list[int]] = []
    for x0, x1, iy in runs:
        for rect in rects:
            if rect[0] == x0 and rect[2] == x1 and rect[3] == iy:
                rect[3] = iy + 1
                break
        else:
            rects.append([x0, iy, x1, iy + 1])
    return [tuple(r) for r in rects]


def _newell_normal(corners: np.ndarray) -> np.ndarray:
    """Area-weighted normal (right-hand rule) of a planar polygon, convex or not (Newell's method)."""
    after = np.roll(corners, -1, axis=0)
    return 0.5 * np.cross(corners, after).sum(axis=0)


def _room_faces(scene: Any) -> list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
    """Every reflecting polygon as (room it faces, (K, 3) corners, outward normal, absorption (B,))."""
    if scene.imported:
        return [(face.room, np.asarray(face.corners, float), np.asarray(face.outward, float),
                 _material_absorption(face.material)) for face in scene.surfaces]
    cell_room = {tuple(map(int, c)): i for i, room in enumerate(scene.rooms) for c in room.cells}
    faces = []
    for wall in scene.walls:
        p0, p1 = np.asarray(wall.p0, float), np.asarray(wall.p1, float)
        along = p1 - p0
        side = np.array([-along[1], along[0]]) / np.linalg.norm(along)  # a unit normal in plan
        corners = np.array([[*p0, wall.z0], [*p1, wall.z0], [*p1, wall.z1], [*p0, wall.z1]])
        mid = (p0 + p1) / 2
        for sign in (1.0, -1.0):
            room = cell_room.get(tuple(np.floor(mid + 0.5 * sign * side).astype(int)), -1)
            if room >= 0:  # a room on this side: face it, normal away from it, in its finish
                faces.append((room, corners, np.array([*(-sign * side), 0.0]),
                              _material_absorption(scene.rooms[room].wall_material)))
    for index, room in enumerate(scene.rooms):
        floor, ceiling = _material_absorption(room.floor_material), _material_absorption(room.ceiling_material)
        for x0, y0, x1, y1 in _cell_rectangles(room.cells):
            flat = np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])
            faces.append((index, flat, np.array([0.0, 0.0, -1.0]), floor))
            faces.append((index, flat + [0, 0, scene.height], np.array([0.0, 0.0, 1.0]), ceiling))
    return faces


def _face_area(corners: np.ndarray) -> float:
    if len(corners) == 4 and np.allclose(corners[2] - corners[1], corners[3] - corners[0]) \
            and abs(np.dot(corners[1] - corners[0], corners[3] - corners[0])) < 1e-9:
        # A rectangle (every face of a generated scene): its sides' product, as the banks were built with.
        return float(np.linalg.norm(corners[1] - corners[0]) * np.linalg.norm(corners[3] - corners[0]))
    return float(np.linalg.norm(_newell_normal(corners)))


def furnishing_area(scene: Any, room_index: int) -> np.ndarray:
    """(B,) equivalent absorption area (m^2) of a room's furnishing and of its furniture boxes.

    Furnishing: sum over its (material, m^2 per m^2 of floor) of floor area x coverage x absorption.
    A furniture box adds its top and four sides times its material's absorption.
    """
    room = scene.rooms[room_index]
    area = np.zeros(BAND_CENTRES.size)
    for material, coverage in FURNISHINGS[room.furnishing]:
        area += room.area * coverage * _material_absorption(material)
    for box in scene.obstacles:
        if scene.room_at(((box.xmin + box.xmax) / 2, (box.ymin + box.ymax) / 2)) == room_index:
            width, depth = box.xmax - box.xmin, box.ymax - box.ymin
            surface = width * depth + 2 * (width + depth) * box.height
            area += surface * _material_absorption(box.material)
    return area


def _effective_faces(scene: Any) -> list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
    """``_room_faces`` with each room's furnishing area spread evenly over the faces of that room.

    A face's absorption a becomes a + A_f / S (A_f the room's furnishing area, S its surface, capped
    at _MAX_ABSORPTION): the room keeps its total absorption and stays a diffuse field, which is
    what Eyring's formula assumes, and the ray tracer's decay then follows it.
    """
    faces = _room_faces(scene)
    surface = np.zeros(len(scene.rooms))
    for room, corners, _, _ in faces:
        surface[room] += _face_area(corners)
    extra = np.stack([furnishing_area(scene, r) for r in range(len(scene.rooms))]) / surface[:, None]
    return [(room, corners, outward, np.minimum(absorption + extra[room], _MAX_ABSORPTION))
            for room, corners, outward, absorption in faces]


def scene_surfaces(scene: Any, config: AcousticsConfig) -> list[libroom.Wall]:
    """All reflecting polygons of a scene as libroom walls (see the module docstring)."""
    return [_polygon(corners, outward, absorption, config.scattering)
            for _, corners, outward, absorption in _effective_faces(scene)]


def _walls_crossed(scene: Any, start: np.ndarray, ends: np.ndarray, height: float) -> np.ndarray:
    """Number of walls spanning ``height`` that the plan segments start -> ends[i] cross properly."""
    walls = [w for w in scene.walls if w.z0 <= height <= w.z1]
    if not walls:
        return np.zeros(len(ends), dtype=int)
    a = np.array([w.p0 for w in walls], float)[None]  # (1, W, 2)
    b = np.array([w.p1 for w in walls], float)[None]
    p, q = start[None, None, :2], ends[:, None, :2]  # (1,1,2), (R,1,2)

    def cross(o, u, v):
        return (u[..., 0] - o[..., 0]) * (v[..., 1] - o[..., 1]) - (u[..., 1] - o[..., 1]) * (v[..., 0] - o[..., 0])

    d1, d2 = cross(a, b, p), cross(a, b, q)
    d3, d4 = cross(p, q, a), cross(p, q, b)
    proper = (d1 * d2 < 0) & (d3 * d4 < 0)
    if scene.imported:  # an imported wall is solid between two faces: a path through it crosses both
        return (proper.sum(axis=1) + 1) // 2
    return proper.sum(axis=1)


# ----------------------------------------------------------------------------- spectra helpers


def _band_weights(n_fft: int, sample_rate: int) -> np.ndarray:
    """(B, F) squared band weights, hats in log-frequency between octave centres, summing to 1."""
    freqs = np.fft.rfftfreq(n_fft, 1.0 / sample_rate)
    logf = np.log2(np.clip(freqs, BAND_CENTRES[0], BAND_CENTRES[-1]))
    logc = np.log2(BAND_CENTRES)
    eye = np.eye(BAND_CENTRES.size)
    return np.stack([np.interp(logf, logc, eye[b]) for b in range(BAND_CENTRES.size)])


def _air_amplitude(distance: np.ndarray, config: AcousticsConfig) -> np.ndarray:
    """(..., B) amplitude factor of air absorption over ``distance`` metres."""
    if not config.air_absorption:
        return np.ones(np.shape(distance) + (BAND_CENTRES.size,))
    from pyroomacoustics.parameters import Physics

    air = Physics().get_air_absorption()
    alpha = np.interp(np.log2(BAND_CENTRES), np.log2(air["center_freqs"]), air["coeffs"])
    return np.exp(-0.5 * alpha * np.asarray(distance)[..., None])


def _heading_frames() -> np.ndarray:
    """(4, 3, 3) world->head rotations; heading h faces h*90 deg counter-clockwise from +x."""
    angles = np.arange(N_HEADINGS) * np.pi / 2
    c, s = np.cos(angles), np.sin(angles)
    zero, one = np.zeros_like(c), np.ones_like(c)
    front, left = np.stack([c, s, zero], -1), np.stack([-s, c, zero], -1)
    up = np.stack([zero, zero, one], -1)
    return np.stack([front, left, up], axis=1)


# ----------------------------------------------------------------------------- simulation


def _early_part(vectors: np.ndarray, gains: np.ndarray, hrtf: Hrtf, hrtf_spectra: np.ndarray,
                weights: np.ndarray, config: AcousticsConfig) -> np.ndarray:
    """(4, 2, E) binaural sum of images: head->image ``vectors`` (K, 3), per-band ``gains`` (K, B)."""
    n_early = config.n_early
    distance = np.linalg.norm(vectors, axis=-1)
    shift = np.maximum(distance, config.min_distance) / config.speed_of_sound * config.sample_rate
    shift = shift - hrtf.centre_delay
    keep = shift + hrtf.hrirs.shape[-1] < n_early  # later images would wrap around the window
    vectors, gains, shift = vectors[keep], gains[keep], shift[keep]
    if len(shift) == 0:
        return np.zeros((N_HEADINGS, 2, n_early), np.float32)
    bins = np.arange(weights.shape[1])
    response = (gains @ weights) * np.exp(-2j * np.pi * np.outer(shift, bins) / n_early)  # (K, F)
    head_vectors = np.einsum("hij,kj->hki", _heading_frames(), vectors)
    directions = hrtf.nearest(head_vectors)  # (4, K)
    spectra = np.einsum("hkef,kf->hef", hrtf_spectra[directions], response.astype(np.complex64))
    return sfft.irfft(spectra, n_early, axis=-1).astype(np.float32)


def _late_part(histograms: np.ndarray, direct_delay: np.ndarray, weights: np.ndarray,
               rng: np.random.Generator, config: AcousticsConfig, *, ear_spacing: float) -> np.ndarray:
    """(R, 2, T) binaural diffuse tails from (R, B, bins) energy histograms, silent before each
    receiver's ``direct_delay`` (samples): nothing arrives before the direct sound."""
    n_rec, n_taps = histograms.shape[0], config.n_taps
    spectra = sfft.rfft(rng.standard_normal((n_rec, 2, n_taps)), axis=-1)  # (R, 2, F)
    # White noise of unit variance split into bands: each band keeps its share of the spectrum,
    # as in pyroomacoustics (every band's histogram holds the energy of a full-band ray).
    band_noise = sfft.irfft(spectra[:, :, None, :] * np.sqrt(weights), n_taps, axis=-1)  # (R, 2, B, T)
    coherence = np.sinc(2 * BAND_CENTRES * ear_spacing / config.speed_of_sound)
    same, diff = np.sqrt((1 + coherence) / 2), np.sqrt(np.maximum(1 - coherence, 0) / 2)
    left = same[:, None] * band_noise[:, 0] + diff[:, None] * band_noise[:, 1]
    right = same[:, None] * band_noise[:, 0] - diff[:, None] * band_noise[:, 1]
    # Energy per bin -> energy per sample, linearly interpolated at bin centres.
    samples_per_bin = config.hist_bin * config.sample_rate
    bin_times = (np.arange(histograms.shape[-1]) + 0.5) * samples_per_bin
    taps = np.arange(n_taps)
    flat = histograms.reshape(-1, histograms.shape[-1]) / samples_per_bin
    power = np.stack([np.interp(taps, bin_times, h, left=0.0, right=0.0) for h in flat])
    envelope = np.sqrt(np.maximum(power, 0)).reshape(n_rec, -1, n_taps)
    envelope *= taps >= np.floor(direct_delay)[:, None, None]
    if config.air_absorption:
        envelope *= np.moveaxis(_air_amplitude(taps / config.sample_rate * config.speed_of_sound, config), -1, 0)
    return np.stack([(envelope * left).sum(1), (envelope * right).sum(1)], axis=1).astype(np.float32)


def receiver_positions(scene: Any, config: AcousticsConfig) -> np.ndarray:
    """(N, 3) ear/source positions: every grid node at head height."""
    xy = np.asarray(scene.grid.positions, dtype=np.float64)
    return np.column_stack([xy, np.full(len(xy), config.head_height)])


def simulate_source(scene: Any, source_node: int, config: AcousticsConfig, *,
                    surfaces: list | None = None) -> np.ndarray:
    """(N, row_length) rows of the bank for one source node: early (4,2,E) then late (2,T) per receiver."""
    if config.backend == "rlr":
        from m2h_ros.core.world import rlr_backend

        return rlr_backend.simulate_source(scene, source_node, config)
    hrtf = load_head(config.head, config.sample_rate)
    points = receiver_positions(scene, config)
    if not 0 <= source_node < len(points):
        raise ConfigError(f"source node {source_node} is not a node of scene {scene.scene_id}")
    source = points[source_node]
    from pyroomacoustics import libroom
    from pyroomacoustics.doa import fibonacci_spherical_sampling

    surfaces = scene_surfaces(scene, config) if surfaces is None else surfaces
    engine = libroom.Room(surfaces, list(range(len(surfaces))), [], config.speed_of_sound,
                          config.ism_max_order, 1e-6, config.rir_length, config.receiver_radius,
                          config.hist_bin, config.tail)
    for point in points:
        engine.add_mic(point.astype(np.float32)[:, None])
    n_images = engine.image_source_model(source.astype(np.float32))
    if n_images:
        images = np.asarray(engine.sources, np.float64).T  # (I, 3)
        reflection = np.asarray(engine.attenuations, np.float64).T  # (I, B)
        visible = np.asarray(engine.visible_mics, bool)  # (N, I)
        direct = np.asarray(engine.orders) == 0
    else:
        images, reflection = np.zeros((0, 3)), np.zeros((0, BAND_CENTRES.size))
        visible, direct = np.zeros((len(points), 0), bool), np.zeros(0, bool)

    crossed = _walls_crossed(scene, source, points, config.head_height)
    transmission = np.where(crossed > 0, 10.0 ** (-config.wall_transmission_db * np.maximum(crossed, 1) / 20.0), 1.0)

    n_early = config.n_early
    weights = _band_weights(n_early, config.sample_rate)
    hrtf_spectra = sfft.rfft(hrtf.hrirs, n_early, axis=-1).astype(np.complex64)
    rows = np.zeros((len(points), config.row_length), np.float32)
    for r, point in enumerate(points):
        sel = visible[r]
        vectors, bands = images[sel] - point, reflection[sel]
        if not (sel & direct).any() and transmission[r] > 0:  # blocked direct path: through walls
            vectors = np.vstack([vectors, source - point])
            bands = np.vstack([bands, np.full(BAND_CENTRES.size, transmission[r])])
        distance = np.maximum(np.linalg.norm(vectors, axis=-1), config.min_distance)
        gains = bands * _air_amplitude(distance, config) / distance[:, None]
        early = _early_part(vectors, gains, hrtf, hrtf_spectra, weights, config)
        rows[r, : N_HEADINGS * 2 * n_early] = early.ravel()

    if config.tail:
        directions = fibonacci_spherical_sampling(config.n_rays).T.astype(np.float32)
        for mic in engine.microphones:
            mic.make_omnidirectional()
        libroom.set_rng_seed(int(config.seed) * 100_003 + int(source_node))  # scattering draws
        engine.ray_tracing(directions, np.ones((config.n_rays, BAND_CENTRES.size), np.float32),
                           source.astype(np.float32))
        n_bins = int(np.ceil(config.rir_length / config.hist_bin))
        histograms = np.zeros((len(points), BAND_CENTRES.size, n_bins))
        for r, mic in enumerate(engine.microphones):
            hist = np.asarray(mic.histograms[0].get_hist())[:, :n_bins]
            histograms[r, :, : hist.shape[1]] = hist
        rng = np.random.default_rng([config.seed, int(source_node)])
        direct_delay = np.linalg.norm(points - source, axis=1) / config.speed_of_sound * config.sample_rate
        late = _late_part(histograms, direct_delay, _band_weights(config.n_taps, config.sample_rate), rng, config,
                          ear_spacing=hrtf.ear_spacing or config.head_width)
        rows[:, N_HEADINGS * 2 * n_early:] = late.reshape(len(points), -1)
    return rows.astype(config.storage_dtype)


def assemble(rows: np.ndarray, headings: np.ndarray, config: AcousticsConfig) -> np.ndarray:
    """(B, 2, T) float32 binaural RIRs from (B, row_length) stored rows and (B,) headings."""
    n_early, n_taps = config.n_early, config.n_taps
    batch = len(rows)
    out = np.array(rows[:, N_HEADINGS * 2 * n_early:], dtype=np.float32).reshape(batch, 2, n_taps)
    early = rows[:, : N_HEADINGS * 2 * n_early].reshape(batch, N_HEADINGS, 2, n_early)
    out[..., :n_early] += early[np.arange(batch), headings]
    return out


# ----------------------------------------------------------------------------- rendering


def render_binaural(clips: np.ndarray, rirs: np.ndarray) -> np.ndarray:
    """(B, 2, S) float32: each clip (B, S) convolved with its binaural RIR (B, 2, T).

    Causal: the first S samples of the full convolution, so the direct sound arrives after its
    propagation delay. The original Move2Hear code used ``scipy.signal.fftconvolve(mode="same")``,
    which keeps the centred S samples and so advances the output by T // 2 samples.
    """
    clips, rirs = np.asarray(clips, np.float32), np.asarray(rirs, np.float32)
    if clips.ndim != 2 or rirs.ndim != 3 or rirs.shape[1] != 2 or len(clips) != len(rirs):
        raise ConfigError(f"render_binaural needs clips (B, S) and rirs (B, 2, T), got {clips.shape}, {rirs.shape}")
    n_samples = clips.shape[1]
    n_fft = sfft.next_fast_len(n_samples + rirs.shape[2] - 1, real=True)
    spectrum = sfft.rfft(clips, n_fft, axis=-1)[:, None, :] * sfft.rfft(rirs, n_fft, axis=-1)
    return sfft.irfft(spectrum, n_fft, axis=-1)[..., :n_samples].astype(np.float32)


def mix(renders: np.ndarray) -> np.ndarray:
    """Mixture of K binaural renders (K, B, 2, S): their sum divided by K (the original code's rule)."""
    renders = np.asarray(renders)
    if renders.ndim != 4 or renders.shape[0] == 0:
        raise ConfigError(f"mix needs renders of shape (K, B, 2, S) with K >= 1, got {renders.shape}")
    return (renders.sum(axis=0) / renders.shape[0]).astype(np.float32)


# ----------------------------------------------------------------------------- reverberation time


def room_rt60(scene: Any, room_index: int, *, formula: str = "eyring", air: bool = True) -> np.ndarray:
    """(B,) Sabine or Eyring RT60 (s) per octave band (BAND_CENTRES) of one room.

    From the faces the simulation uses (each wall side with its own material, the furnishing
    spread over the room); door gaps are open, neither surface nor absorption. ``air`` adds the
    air's absorption area 4 m V (m: energy attenuation per metre, as the simulation applies it).
    """
    if not 0 <= room_index < len(scene.rooms):
        raise ConfigError(f"room {room_index} is not a room of scene {scene.scene_id}")
    surface, absorption = 0.0, np.zeros(BAND_CENTRES.size)
    for room, corners, _, alpha in _effective_faces(scene):
        if room == room_index:
            area = _face_area(corners)
            surface += area
            absorption += area * alpha
    volume = scene.rooms[room_index].area * scene.height
    if formula == "sabine":
        equivalent = absorption
    elif formula == "eyring":
        equivalent = -surface * np.log(1 - absorption / surface)
    else:
        raise ConfigError(f"formula must be 'sabine' or 'eyring', got {formula!r}")
    if air:
        equivalent = equivalent - 8 * volume * np.log(_air_amplitude(np.ones(()), AcousticsConfig()))
    return 0.161 * volume / equivalent


def octave_band(signal: np.ndarray, centre: float, sample_rate: int) -> np.ndarray:
    """``signal`` filtered (zero phase) to the octave band around ``centre`` Hz."""
    from scipy.signal import butter, sosfiltfilt

    sos = butter(4, [centre / np.sqrt(2), min(centre * np.sqrt(2), 0.49 * sample_rate)],
                 btype="bandpass", fs=sample_rate, output="sos")
    return sosfiltfilt(sos, np.asarray(signal, np.float64), axis=-1)


def measure_rt60(rir: np.ndarray, sample_rate: int, *, decay_db: float = 20.0) -> float:
    """RT60 (s) from Schroeder backward integration: fit between -5 dB and -5-decay_db (T20/T30)."""
    energy = np.cumsum(np.asarray(rir, np.float64)[::-1] ** 2)[::-1]
    curve = 10 * np.log10(energy / energy[0] + 1e-300)
    start, stop = np.argmax(curve <= -5.0), np.argmax(curve <= -5.0 - decay_db)
    if stop <= start:
        raise ConfigError(f"the RIR does not decay by {5 + decay_db} dB: too short to measure RT60")
    times = np.arange(start, stop) / sample_rate
    slope = np.polyfit(times, curve[start:stop], 1)[0]
    return float(-60.0 / slope)


def measured_room_rt60(scene: Any, room_index: int, config: AcousticsConfig, *, n_sources: int = 2,
                       n_receivers: int = 3, min_distance: float = 1.5) -> np.ndarray:
    """(B,) median Schroeder T20 RT60 (s) per octave band over RIRs inside one room.

    The RIRs come from ``simulate_source`` and ``assemble`` (the bank's own code path): up to
    ``n_sources`` source nodes of the room, each heard at up to ``n_receivers`` nodes of the same
    room at least ``min_distance`` m away (both ears, heading 0), so the direct sound does not
    dominate the fit.
    """
    nodes = np.flatnonzero(scene.grid.room_of == room_index)
    if len(nodes) < 2:
        raise ConfigError(f"room {room_index} of scene {scene.scene_id} has fewer than 2 nodes")
    positions = np.asarray(scene.grid.positions, float)
    estimates = []
    for source in nodes[np.linspace(0, len(nodes) - 1, min(n_sources, len(nodes))).astype(int)]:
        far = nodes[np.linalg.norm(positions[nodes] - positions[source], axis=1) >= min_distance]
        if len(far) == 0:
            continue
        receivers = far[np.linspace(0, len(far) - 1, min(n_receivers, len(far))).astype(int)]
        rows = simulate_source(scene, int(source), config)
        rirs = assemble(np.asarray(rows[receivers]), np.zeros(len(receivers), int), config)
        estimates.append([[measure_rt60(octave_band(ear, centre, config.sample_rate), config.sample_rate)
                           for centre in BAND_CENTRES] for rir in rirs for ear in rir])
    if not estimates:
        raise ConfigError(f"room {room_index} of scene {scene.scene_id} has no node pair "
                          f"{min_distance} m apart")
    return np.median(np.concatenate(estimates), axis=0)
