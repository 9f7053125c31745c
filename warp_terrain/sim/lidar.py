"""LIDAR sensor configuration: one dataclass, and presets that are data with their sources.

A :class:`LidarConfig` describes a spinning multi-beam LIDAR the way its datasheet does: an
explicit table of vertical (elevation) angles, one per channel, in degrees; a horizontal step;
a range window; range noise and dropout; and the mount height above the ground. It is a plain
dataclass with plain field types so Hydra/OmegaConf can use it as a structured config, and
:meth:`LidarConfig.ray_directions` turns it into the unit ray directions the ray-casting kernel
consumes. Degrees appear only here, in the user-facing spec; everything downstream is radians.

Presets (``lidar_preset(name)`` returns a fresh copy):

========== ==== ============= ========== ========= ======= =====================================
name       ch.  elevations    az. step   range     noise   vertical-angle table from
========== ==== ============= ========== ========= ======= =====================================
vlp16      16   -15 .. +15    0.2 deg    0.5-100 m 0.03 m  Velodyne VLP-16 User Manual 63-9243
                                                           Rev. D, Table 9-1 (2 deg steps)
hdl32e     32   -30.67..10.67 0.16 deg   .05-100 m 0.02 m  Velodyne HDL-32E User's Manual 63-9113,
                                                           laser firing order / vertical angle
                                                           table (4/3 deg steps, as printed)
hdl64e     64   -24.56..+1.96 0.1728 deg 1-120 m   0.02 m  per-laser factory calibration of an
                                                           HDL-64E S3 ("vert_correction", rad),
                                                           ros-drivers/velodyne,
                                                           velodyne_pointcloud/params/
                                                           64e_s3-xiesc.yaml
os1-64     64   -21.41..21.02 360/2048   0.5-120 m 0.03 m  Ouster OS-1-64-U02 (gen 2, uniform
                                                           beams) sensor metadata,
                                                           "beam_altitude_angles",
                                                           ouster-lidar/ouster-sdk,
                                                           ouster_ros/metadata/os1_64.json
os1-128    128  -21.62..21.34 360/2048   0.5-120 m 0.03 m  Ouster OS-1-128 (gen 2) sensor
                                                           metadata, "beam_altitude_angles",
                                                           ouster-lidar/ouster-sdk,
                                                           tests/metadata/
                                                           2_3_1_os-992146000760-128.json
========== ==== ============= ========== ========= ======= =====================================

Simplifications (deliberate; the scan is an elevation-map input, not a packet-level emulator):
every channel fires at the same azimuth (Ouster ``beam_azimuth_angles`` staggering and Velodyne
``rot_correction`` are ignored), all beams start at one optical centre (Velodyne
``vert_offset_correction`` and Ouster ``lidar_origin_to_beam_origin_mm`` are ignored), and a
scan is instantaneous. ``range_noise_std`` is set to the datasheet range accuracy, read as a
1-sigma Gaussian. The per-preset ``source`` strings say which numbers are from a document and
which are our assumptions.
"""

import copy
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields

import numpy as np

from ..core.checks import check_finite, require

__all__ = ["LidarConfig", "LIDAR_PRESETS", "lidar_preset", "lidar_preset_names"]


def _vlp16_elevations() -> list[float]:
    return [float(e) for e in range(-15, 16, 2)]


@dataclass
class LidarConfig:
    """A spinning multi-beam LIDAR, in datasheet units (degrees, metres).

    Rays cover azimuths ``azimuth_start_deg + k * azimuth_step_deg`` for
    ``k = 0 .. columns - 1`` (``columns = round(fov_deg / azimuth_step_deg)``), measured in the
    sensor frame from +x (forward) towards +y; elevation is measured up from the horizontal
    plane. The defaults are the VLP-16's geometry under the name ``"custom"``.
    """

    name: str = "custom"
    # Vertical angle of each channel, degrees; kept sorted ascending (see __post_init__).
    elevations_deg: list[float] = field(default_factory=_vlp16_elevations)
    azimuth_step_deg: float = 0.2
    azimuth_start_deg: float = 0.0
    fov_deg: float = 360.0
    min_range: float = 0.5
    max_range: float = 100.0
    range_noise_std: float = 0.03
    dropout: float = 0.0
    mount_height: float = 1.8
    source: str = "user-defined"

    def __post_init__(self) -> None:
        # Store the table sorted ascending (ring 0 = lowest beam), as plain floats, and as a
        # list of our own so the caller's list (or a preset's) is never aliased.
        try:
            self.elevations_deg = sorted(float(e) for e in self.elevations_deg)
        except (TypeError, ValueError):
            pass  # left as given; validate() reports the field by name

    # ---------------------------------------------------------------- derived sizes
    @property
    def channels(self) -> int:
        """Number of beams (rings)."""
        return len(self.elevations_deg)

    @property
    def columns(self) -> int:
        """Number of azimuth steps per scan: ``round(fov_deg / azimuth_step_deg)``."""
        return int(round(float(self.fov_deg) / float(self.azimuth_step_deg)))

    @property
    def num_rays(self) -> int:
        """Rays per scan, ``channels * columns``."""
        return self.channels * self.columns

    # ---------------------------------------------------------------- validation
    def validate(self) -> "LidarConfig":
        """Check every field; raise ``ValueError`` naming the offending field. Returns self."""
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in ("name", "source"):
                require(isinstance(value, str), f.name, value, "must be a string")
                require(f.name != "name" or value.strip() != "", f.name, value, "must be a non-empty label")
            elif f.name != "elevations_deg":
                require(isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool), f.name, value, "must be a real number")
                check_finite(f.name, value)

        elev = self.elevations_deg
        require(not isinstance(elev, (str, bytes)) and isinstance(elev, (Sequence, np.ndarray)), "elevations_deg", elev,
                "must be a list of angles in degrees")
        require(len(elev) > 0, "elevations_deg", elev, "must list at least one channel angle")
        for i, e in enumerate(elev):
            require(isinstance(e, (int, float, np.integer, np.floating)) and not isinstance(e, bool), f"elevations_deg[{i}]", e, "must be a real number")
            check_finite(f"elevations_deg[{i}]", e)
            require(-90.0 <= float(e) <= 90.0, f"elevations_deg[{i}]", e, "is outside [-90, 90] degrees")

        require(self.azimuth_step_deg > 0.0, "azimuth_step_deg", self.azimuth_step_deg, "must be > 0")
        require(0.0 < self.fov_deg <= 360.0, "fov_deg", self.fov_deg, "must be in (0, 360]")
        require(self.columns >= 1, "azimuth_step_deg", self.azimuth_step_deg,
                f"is too large for fov_deg={self.fov_deg}: round(fov_deg / azimuth_step_deg) gives no columns")
        require(self.min_range >= 0.0, "min_range", self.min_range, "must be >= 0 m")
        require(self.max_range > self.min_range, "max_range", self.max_range, f"must be greater than min_range ({self.min_range} m)")
        require(self.range_noise_std >= 0.0, "range_noise_std", self.range_noise_std, "must be >= 0 m")
        require(0.0 <= self.dropout < 1.0, "dropout", self.dropout, "must be in [0, 1)")
        require(self.mount_height > 0.0, "mount_height", self.mount_height, "must be > 0 m")
        return self

    # ---------------------------------------------------------------- geometry
    def elevations_rad(self) -> np.ndarray:
        """``(channels,)`` float64 elevation of each ring in radians, ascending."""
        return np.radians(np.sort(np.asarray(self.elevations_deg, dtype=np.float64)))

    def azimuths_deg(self) -> np.ndarray:
        """``(columns,)`` float64 azimuth of each column in degrees (not wrapped)."""
        k = np.arange(self.columns, dtype=np.float64)
        return float(self.azimuth_start_deg) + k * float(self.azimuth_step_deg)

    def ray_directions(self) -> np.ndarray:
        """Unit ray directions in the sensor frame (x forward, y left, z up).

        Returns ``(num_rays, 3)`` float32; row ``ring * columns + column`` is the ray of ring
        ``ring`` (0 = lowest elevation) at azimuth ``azimuth_start_deg + column *
        azimuth_step_deg``: ``(cos e cos a, cos e sin a, sin e)``. Computed in float64.
        """
        self.validate()
        e = self.elevations_rad()[:, None]  # (channels, 1)
        a = np.radians(self.azimuths_deg())[None, :]  # (1, columns)
        ce = np.cos(e)
        d = np.stack(
            np.broadcast_arrays(ce * np.cos(a), ce * np.sin(a), np.sin(e)), axis=-1
        )  # (channels, columns, 3)
        return np.ascontiguousarray(d.reshape(-1, 3), dtype=np.float32)


# ------------------------------------------------------------------------------------ tables
# Each table is typed in the order its source lists it; LidarConfig sorts it ascending.

# Velodyne HDL-32E User's Manual 63-9113, vertical angle per laser as printed (firing order
# DSR 0..31). The manual prints -26.66 and -6.66 where the 4/3-degree progression rounds to
# -26.67 / -6.67; we keep the printed values. The ROS driver's standard table
# (ros-drivers/velodyne velodyne_pointcloud/params/32db.yaml, radians) agrees to 0.01 deg.
_HDL32E_DEG = (
    -30.67, -9.33, -29.33, -8.00, -28.00, -6.66, -26.66, -5.33,
    -25.33, -4.00, -24.00, -2.67, -22.67, -1.33, -21.33, 0.00,
    -20.00, 1.33, -18.67, 2.67, -17.33, 4.00, -16.00, 5.33,
    -14.67, 6.67, -13.33, 8.00, -12.00, 9.33, -10.67, 10.67,
)

# HDL-64E S3 per-laser "vert_correction" (radians) by laser_id 0..63, from the factory
# calibration published as ros-drivers/velodyne velodyne_pointcloud/params/64e_s3-xiesc.yaml.
# Lasers 0-31 are the upper block (about +1.96 .. -8.56 deg, ~1/3 deg apart), 32-63 the lower
# block (about -8.77 .. -24.56 deg, ~1/2 deg apart); the S3 manual's nominal vertical FOV is
# +2 .. -24.9 deg. Individual angles deviate from an even spread, as real units do.
_HDL64E_S3_VERT_CORRECTION_RAD = (
    -0.1261818455292898, -0.11953745909742221, 0.00356118725906175, 0.010306535403103584,
    -0.1144967440141401, -0.10803612329921503, -0.14944538101702426, -0.14344353231329066,
    -0.10278016723125998, -0.09569590023202451, -0.1386345201601863, -0.13181073657049397,
    -0.054438932963427306, -0.048730533448148504, -0.08961595328025192, -0.0839353306800186,
    -0.043427018903405855, -0.03648801216715539, -0.07906187922560139, -0.07255814015150577,
    -0.031587736747464255, -0.025460288914769372, -0.06665878416276627, -0.06055112836378901,
    0.015620435355027301, 0.022567997346205196, -0.019943931467746017, -0.013200099491225388,
    0.027266617424120905, 0.03421014630846329, -0.007885903531460533, -0.0015491891506552067,
    -0.39021216204755743, -0.38355018793281753, -0.197138848550284, -0.18768579625563228,
    -0.3750836655445631, -0.36762882325722723, -0.4285668719175616, -0.4214410765541042,
    -0.3565455112681652, -0.34717860842539194, -0.4110102035460227, -0.40083030888437793,
    -0.2840315837972709, -0.27761533458791926, -0.3359268721635124, -0.33026751989087316,
    -0.26851710773019805, -0.26051854302098837, -0.3216451745070007, -0.3135280670349956,
    -0.24941678290173272, -0.2409525119882134, -0.30313513748485243, -0.29323634555253386,
    -0.17760463486977288, -0.17006926832673774, -0.22974121500510264, -0.22391891879349718,
    -0.16231529056824404, -0.15314424682880032, -0.21457119711920336, -0.2079266762969834,
)

# Ouster OS-1-64-U02 (gen 2, uniform beam spacing; fw v2.0.0, prod_sn 122103000554)
# "beam_altitude_angles" (degrees, top to bottom) from ouster-lidar/ouster-sdk
# ouster_ros/metadata/os1_64.json. Per-unit calibration: spans +21.02 .. -21.41, not the
# nominal +-22.5 of the 45-degree marketing FOV.
_OS1_64_GEN2_DEG = (
    21.02, 20.39, 19.76, 19.15, 18.5, 17.86, 17.21, 16.58,
    15.91, 15.27, 14.6, 13.94, 13.26, 12.6, 11.9, 11.24,
    10.55, 9.87, 9.18, 8.48, 7.77, 7.09, 6.38, 5.69,
    4.99, 4.3, 3.59, 2.9, 2.19, 1.48, 0.77, 0.06,
    -0.65, -1.34, -2.06, -2.76, -3.46, -4.17, -4.85, -5.57,
    -6.27, -6.95, -7.66, -8.34, -9.04, -9.73, -10.42, -11.09,
    -11.76, -12.45, -13.12, -13.78, -14.45, -15.09, -15.76, -16.41,
    -17.06, -17.69, -18.32, -18.95, -19.57, -20.19, -20.8, -21.41,
)

# Ouster OS-1-128 (gen 2; prod_pn 840-103575-06, prod_sn 992146000760, fw v2.3.1-rc.1)
# "beam_altitude_angles" (degrees, top to bottom) from ouster-lidar/ouster-sdk
# tests/metadata/2_3_1_os-992146000760-128.json. Spans +21.34 .. -21.62.
_OS1_128_GEN2_DEG = (
    21.34, 21.03, 20.72, 20.41, 20.08, 19.78, 19.48, 19.17,
    18.83, 18.51, 18.21, 17.88, 17.56, 17.23, 16.92, 16.59,
    16.26, 15.94, 15.61, 15.28, 14.93, 14.6, 14.27, 13.95,
    13.61, 13.26, 12.94, 12.6, 12.26, 11.91, 11.58, 11.24,
    10.89, 10.55, 10.21, 9.88, 9.52, 9.18, 8.83, 8.5,
    8.14, 7.78, 7.46, 7.11, 6.75, 6.39, 6.05, 5.7,
    5.33, 4.99, 4.64, 4.29, 3.94, 3.59, 3.24, 2.88,
    2.52, 2.18, 1.81, 1.48, 1.11, 0.76, 0.4, 0.05,
    -0.3, -0.67, -1.01, -1.37, -1.75, -2.08, -2.43, -2.79,
    -3.15, -3.5, -3.86, -4.2, -4.56, -4.9, -5.27, -5.6,
    -5.96, -6.32, -6.68, -7.0, -7.38, -7.71, -8.05, -8.41,
    -8.77, -9.11, -9.45, -9.79, -10.16, -10.49, -10.83, -11.18,
    -11.54, -11.86, -12.2, -12.55, -12.91, -13.24, -13.58, -13.89,
    -14.26, -14.58, -14.89, -15.21, -15.6, -15.89, -16.22, -16.54,
    -16.88, -17.21, -17.52, -17.85, -18.2, -18.5, -18.82, -19.14,
    -19.47, -19.78, -20.09, -20.38, -20.72, -21.03, -21.33, -21.62,
)

_OUSTER_COMMON = (
    "horizontal: 2048 columns (lidar_mode 2048x10); max range 120 m for gen-2 OS1 (80% "
    "Lambertian target); range_noise_std 0.03 m from the OS1 datasheet's 1-sigma range "
    "repeatability at SNR 100 (+-3 cm); min_range 0.5 m is our assumption (the gen-1 OS1 "
    "datasheet gives 0.8 m; the gen-2 value was not checked)"
)

LIDAR_PRESETS: dict[str, LidarConfig] = {
    "vlp16": LidarConfig(
        name="vlp16",
        elevations_deg=_vlp16_elevations(),
        azimuth_step_deg=0.2,
        min_range=0.5,
        max_range=100.0,
        range_noise_std=0.03,
        source=(
            "vertical angles: Velodyne VLP-16 User Manual 63-9243 Rev. D, Table 9-1 (-15..+15 "
            "deg in 2 deg steps); 0.2 deg azimuth step at 600 RPM (10 Hz), 100 m range and "
            "+-3 cm typical accuracy from the same manual/datasheet; min_range 0.5 m is our "
            "assumption"
        ),
    ),
    "hdl32e": LidarConfig(
        name="hdl32e",
        elevations_deg=list(_HDL32E_DEG),
        azimuth_step_deg=0.16,
        min_range=0.05,
        max_range=100.0,
        range_noise_std=0.02,
        source=(
            "vertical angles: Velodyne HDL-32E User's Manual and Programming Guide 63-9113, "
            "laser firing order / vertical angle table (-30.67..+10.67 deg, printed to 0.01 "
            "deg), cross-checked with ros-drivers/velodyne "
            "velodyne_pointcloud/params/32db.yaml; 0.16 deg azimuth step at 10 Hz, valid data "
            "range 5 cm to 100 m (manual, Fig. 1; the datasheet quotes 80-100 m), +-2 cm "
            "accuracy"
        ),
    ),
    "hdl64e": LidarConfig(
        name="hdl64e",
        elevations_deg=[math.degrees(r) for r in _HDL64E_S3_VERT_CORRECTION_RAD],
        azimuth_step_deg=0.1728,
        min_range=1.0,
        max_range=120.0,
        range_noise_std=0.02,
        source=(
            "vertical angles: per-laser factory calibration (vert_correction, radians) of an "
            "HDL-64E S3, ros-drivers/velodyne velodyne_pointcloud/params/64e_s3-xiesc.yaml "
            "(upper block +1.96..-8.56 deg, lower block -8.77..-24.56 deg); 0.1728 deg "
            "azimuth step at 10 Hz (2083 columns), 120 m range (80% reflectivity) and 2 cm "
            "1-sigma accuracy from the HDL-64E S2/S3 specifications; min_range 1.0 m is our "
            "assumption"
        ),
    ),
    "os1-64": LidarConfig(
        name="os1-64",
        elevations_deg=list(_OS1_64_GEN2_DEG),
        azimuth_step_deg=360.0 / 2048,
        min_range=0.5,
        max_range=120.0,
        range_noise_std=0.03,
        source=(
            "vertical angles: beam_altitude_angles of an Ouster OS-1-64-U02 (gen 2, uniform "
            "beams, fw v2.0.0), ouster-lidar/ouster-sdk ouster_ros/metadata/os1_64.json "
            "(+21.02..-21.41 deg; nominal datasheet FOV is 45 deg); " + _OUSTER_COMMON
        ),
    ),
    "os1-128": LidarConfig(
        name="os1-128",
        elevations_deg=list(_OS1_128_GEN2_DEG),
        azimuth_step_deg=360.0 / 2048,
        min_range=0.5,
        max_range=120.0,
        range_noise_std=0.03,
        source=(
            "vertical angles: beam_altitude_angles of an Ouster OS-1-128 (gen 2, fw "
            "v2.3.1), ouster-lidar/ouster-sdk "
            "tests/metadata/2_3_1_os-992146000760-128.json (+21.34..-21.62 deg; nominal "
            "datasheet FOV is 45 deg); " + _OUSTER_COMMON
        ),
    ),
}


def lidar_preset_names() -> list[str]:
    """The preset names :func:`lidar_preset` accepts."""
    return list(LIDAR_PRESETS)


def lidar_preset(name: str, **overrides: object) -> LidarConfig:
    """A fresh, validated copy of the named preset, with optional field overrides.

    ``name`` is matched case-insensitively, with ``_`` read as ``-`` (``"OS1_64"`` works).
    Mutating the result never changes the preset. Raises ``ValueError`` for an unknown name
    (listing the valid ones) or an unknown/invalid override.
    """
    key = str(name).strip().lower().replace("_", "-")
    preset: LidarConfig | None = LIDAR_PRESETS.get(key)
    if preset is None:
        raise ValueError(
            f"unknown LIDAR preset {name!r}; valid presets: {', '.join(LIDAR_PRESETS)}"
        )
    cfg = copy.deepcopy(preset)
    known = {f.name for f in fields(LidarConfig)}
    for k, v in overrides.items():
        if k not in known:
            raise ValueError(f"unknown LidarConfig field {k!r}; fields: {', '.join(sorted(known))}")
        setattr(cfg, k, v)
    if "elevations_deg" in overrides:
        cfg.__post_init__()
    return cfg.validate()
