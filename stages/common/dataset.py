"""Dataset folders (GUIDE section 4): what users bring and what ``fieldloc simulate`` writes.

    DIR/images/        frames, sorted by name (png or jpg)
    DIR/frames.csv     optional: name, stamp (s) per image; without it a numeric file stem is
                       the stamp, otherwise frame index / 30 Hz
    DIR/calib.yaml     camera model (see stages.common.camera)
    DIR/odometry.csv   optional: stamp, dx, dy, dtheta (robot frame, since previous frame)
    DIR/imu.csv        optional: stamp, yaw, collision
    DIR/truth.csv      optional: stamp, x, y, theta (field frame)
    DIR/head.csv       optional, perspective cameras: stamp, pitch, roll of the camera (rad),
                       optionally followed by any of yaw (rad), height (m), x, y (m: the
                       optical centre over the floor in the robot frame), for robots whose
                       head turns and whose camera height changes (imported team frames)

CSV files have a header line with exactly these column names (and, where listed in
``CSV_OPTIONAL_COLUMNS``, some of the optional ones after them); metres and radians.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import DatasetError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
DEFAULT_RATE_HZ = 30.0

CSV_COLUMNS = {
    "frames": ("name", "stamp"),
    "odometry": ("stamp", "dx", "dy", "dtheta"),
    "imu": ("stamp", "yaw", "collision"),
    "truth": ("stamp", "x", "y", "theta"),
    "head": ("stamp", "pitch", "roll"),  # perspective cameras: head angles per frame
}
# columns a file may add after the required ones (any of them, in this order)
CSV_OPTIONAL_COLUMNS = {
    "head": ("yaw", "height", "x", "y"),
}


def read_csv(path: str | Path, kind: str) -> dict[str, np.ndarray]:
    """Read one of the dataset CSVs, checking its header. Returns column -> array."""
    path = Path(path)
    cols = CSV_COLUMNS[kind]
    if not path.is_file():
        raise DatasetError(f"file not found: {path}")
    with open(path, newline="") as f:
        rows = [r for r in csv.reader(f) if r and not r[0].startswith("#")]
    if not rows:
        raise DatasetError(f"{path}: empty; expected a header '{','.join(cols)}'")
    header = [h.strip() for h in rows[0]]
    extra = header[len(cols):]
    optional = CSV_OPTIONAL_COLUMNS.get(kind, ())
    if header[:len(cols)] != list(cols) or extra != [c for c in optional if c in extra]:
        more = f" (then any of '{','.join(optional)}')" if optional else ""
        raise DatasetError(
            f"{path}: expected columns '{','.join(cols)}'{more}, found '{','.join(header)}'"
        )
    cols = tuple(header)
    out = {}
    body = rows[1:]
    for i, name in enumerate(cols):
        if name == "name":
            out[name] = np.array([r[i].strip() for r in body], dtype=object)
            continue
        try:
            out[name] = np.array([float(r[i]) for r in body], dtype=float)
        except (ValueError, IndexError):
            bad = next(
                (n + 2 for n, r in enumerate(body) if len(r) <= i or not _is_float(r[i])), "?"
            )
            raise DatasetError(f"{path}: line {bad}: '{name}' is not a number") from None
    return out


def _is_float(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def write_csv(path: str | Path, kind: str, columns: dict) -> Path:
    from .artifacts import atomic_path

    path = Path(path)
    cols = CSV_COLUMNS[kind] + tuple(c for c in CSV_OPTIONAL_COLUMNS.get(kind, ()) if c in columns)
    n = len(columns[cols[0]])
    with atomic_path(path, suffix=".csv") as tmp:
        with open(tmp, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(cols)
            for i in range(n):
                row = []
                for c in cols:
                    v = columns[c][i]
                    row.append(v if isinstance(v, str) else f"{float(v):.6f}")
                w.writerow(row)
    return path


@dataclass
class Dataset:
    root: Path
    images: list[Path]
    stamps: np.ndarray

    @property
    def names(self) -> list[str]:
        return [p.stem for p in self.images]

    @property
    def calib_path(self) -> Path:
        return self.root / "calib.yaml"

    def camera(self):
        from .camera import load_calib

        return load_calib(self.calib_path)

    def optional(self, kind: str) -> dict[str, np.ndarray] | None:
        p = self.root / f"{kind}.csv"
        return read_csv(p, kind) if p.is_file() else None


def open_dataset(root: str | Path, *, need_images: bool = True) -> Dataset:
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f"dataset folder not found: {root}")
    img_dir = root / "images"
    images = (
        sorted(p for p in img_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if img_dir.is_dir()
        else []
    )
    if need_images and not images:
        raise DatasetError(f"{root}: no images (png or jpg) in {img_dir}")
    frames = root / "frames.csv"
    if frames.is_file():
        tab = read_csv(frames, "frames")
        by_name = dict(zip(tab["name"], tab["stamp"]))
        missing = [p.name for p in images if p.name not in by_name and p.stem not in by_name]
        if missing:
            raise DatasetError(f"{frames}: no stamp for image {missing[0]}")
        stamps = np.array([by_name.get(p.name, by_name.get(p.stem)) for p in images], float)
    elif images and all(_is_float(p.stem) for p in images):
        stamps = np.array([float(p.stem) for p in images])
    else:
        stamps = np.arange(len(images)) / DEFAULT_RATE_HZ
    return Dataset(root=root, images=images, stamps=stamps)


def read_image(path: Path) -> np.ndarray:
    """Read an image as BGR uint8; raises DatasetError if unreadable (callers skip the frame)."""
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise DatasetError(f"unreadable image: {path}")
    return img


def read_mask(path: str | Path, image_size: tuple[int, int]) -> np.ndarray:
    """A dataset's mask image -> bool (h, w), True where the floor may be used. Pixels painted
    pure red (R >= 200, G and B <= 60; the MINHO team's convention) are excluded; a mask without
    red is read as grey levels and its dark pixels (< 128) are excluded."""
    import cv2

    path = Path(path)
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise DatasetError(f"unreadable mask image: {path}")
    w, h = image_size
    if img.shape[:2] != (h, w):
        raise DatasetError(
            f"{path}: mask is {img.shape[1]} x {img.shape[0]} px, the images are {w} x {h}")
    red = (img[..., 2] >= 200) & (img[..., 1] <= 60) & (img[..., 0] <= 60)
    if red.any():
        return ~red
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) >= 128
