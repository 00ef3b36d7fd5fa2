"""BROAD trials (HDF5): real IMU recordings with optical ground truth (Laidig et al. 2021, CC BY 4.0)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from app.core.errors import DataFormatError

FIELDS = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement")


@dataclass(frozen=True)
class BroadTrial:
    """One trial: t (N,) s, gyr rad/s, acc m/s^2, mag uT (device frame), q_ref [w,x,y,z] IMU -> ENU
    (NaN where the optical system lost the markers), movement (N,) bool samples to score."""

    name: str
    t: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray
    q_ref: np.ndarray
    movement: np.ndarray


def load_trial(path: str | Path) -> BroadTrial:

    path = Path(path)
    try:
        with h5py.File(path, "r") as f:
            missing = [k for k in FIELDS if k not in f]
            if missing:
                raise DataFormatError(path, f"not a BROAD trial: missing datasets {missing}")
            rate = float(f.attrs["sampling_rate"])
            data = {k: np.asarray(f[k]) for k in FIELDS}
    except OSError as exc:
        raise DataFormatError(path, f"cannot read HDF5 ({exc})") from exc
    n = len(data["imu_gyr"])
    return BroadTrial(
        path.stem,
        np.arange(n) / rate,
        data["imu_gyr"],
        data["imu_acc"],
        data["imu_mag"],
        data["opt_quat"],
        data["movement"].astype(bool),
    )


def list_trials(folder: str | Path) -> list[Path]:
    return sorted(Path(folder).glob("*.hdf5"))
