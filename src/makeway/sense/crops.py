"""Labelled crop folders, YOLO detection sets, and the held-out split of ``ev_crops`` (issue 3).

**Crop folder** — the format every classifier command reads and writes::

    DIR/images/<name>          any image OpenCV reads (any size; resized on load)
    DIR/labels.csv             header ``image,emergency`` (+ optional ``group``), one row per crop

``emergency`` is ``0`` or ``1``. ``group`` (optional) names the source a crop comes from (a video, a
photo, a log); when present, splits never put one group on both sides. :func:`read_crop_folder`
checks everything up front and raises :class:`~makeway.errors.InputError` naming the file (and the
line) at fault; :func:`write_crop_folder` writes the format.

**YOLO set** — ``DIR/images/<stem>.<ext>`` + ``DIR/labels/<stem>.txt`` with one ``cls cx cy w h``
line per box, normalised to the image size (SPEC §2, YOLO/Darknet txt). An image without a label
file has no boxes. :func:`read_yolo_set` returns the boxes in pixels.

**Held-out split** — the ``ev_crops`` set (Analytics Vidhya) has no source information, and it holds
exact copies (93 crops in 44 sets of identical images, two sets with conflicting labels) and
several shots of one scene. A random split would put copies on both sides and flatter every model.
:func:`split_holdout` therefore splits by *group*: the known source groups when a set has them, otherwise
near-duplicate clusters from :func:`near_duplicate_groups` (grey 32×32 thumbnails, mirror-aware
correlation ≥ 0.85, or an identical 8×8 average hash; connected components). The split is
stratified by label at group level and seeded. The result for ``ev_crops`` is committed as
``makeway/data/ev_crops_holdout.txt`` (:data:`EV_CROPS_HOLDOUT`, written by
``makeway classify holdout``) so every training and evaluation run uses the same parts; the file
carries a fingerprint of the set's image names (:func:`names_fingerprint`) so it is only applied to
the set it was made from.

The crops of ``ambulance_yolo`` (``makeway classify build-ambulance-crops``: one group per source
photo, crop names ``<image stem>_<kind><k>``) have a committed held-out part too: the crops of the
photos listed in ``makeway/data/ambulance_yolo_held_out.txt`` (:data:`AMBULANCE_YOLO_HELD_OUT`, the
images the detector evaluation holds out). :func:`training_split` applies whichever of the two a
crop folder is.
"""

from __future__ import annotations

import csv
import hashlib
import io
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from makeway.atomic import atomic_path, write_text_atomic
from makeway.errors import InputError
from makeway.messages import Box

__all__ = [
    "AMBULANCE_YOLO_HELD_OUT",
    "EV_CROPS_HOLDOUT",
    "IMAGE_SUFFIXES",
    "CropSet",
    "Holdout",
    "YoloImage",
    "ambulance_held_out_split",
    "average_hash",
    "committed_split",
    "holdout_split",
    "names_fingerprint",
    "near_duplicate_groups",
    "near_duplicates_of",
    "read_crop_folder",
    "read_holdout",
    "read_yolo_set",
    "roboflow_source",
    "split_holdout",
    "thumbnail_signatures",
    "training_split",
    "write_crop_folder",
    "write_holdout",
]

#: The committed held-out 20 % of ``ev_crops`` (image names; see the module docstring).
EV_CROPS_HOLDOUT = Path(__file__).resolve().parents[1] / "data" / "ev_crops_holdout.txt"

#: The held-out images of ``ambulance_yolo/valid`` (image names after a ``#`` header), shared by
#: the detector evaluation, the lights split and the crop classifiers' training.
AMBULANCE_YOLO_HELD_OUT = Path(__file__).resolve().parents[1] / "data" / "ambulance_yolo_held_out.txt"

#: File suffixes treated as images in YOLO folders (lower case).
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")

_LABEL_COLUMNS = ("image", "emergency")


# ------------------------------------------------------------------------------------------- crop set


@dataclass(frozen=True, eq=False)
class CropSet:
    """Labelled crops: ``paths[i]`` is an image, ``labels[i]`` its 0/1 label (1 = emergency vehicle).

    ``groups[i]`` is the source group of crop ``i`` (a string id) or ``groups`` is ``None`` when the
    folder does not say. Build with :func:`read_crop_folder`.
    """

    paths: tuple[Path, ...]
    labels: np.ndarray
    groups: np.ndarray | None = None
    root: Path | None = None
    _cache: dict[int, np.ndarray] = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        if len(self.labels) != len(self.paths):
            raise ValueError(f"{len(self.paths)} paths but {len(self.labels)} labels")
        if self.groups is not None and len(self.groups) != len(self.paths):
            raise ValueError(f"{len(self.paths)} paths but {len(self.groups)} groups")

    def __len__(self) -> int:
        return len(self.paths)

    @property
    def names(self) -> list[str]:
        """Image names relative to ``root/images`` (the ``image`` column), or file names."""
        base = self.root / "images" if self.root is not None else None
        out = []
        for p in self.paths:
            try:
                out.append(p.relative_to(base).as_posix() if base is not None else p.name)
            except ValueError:
                out.append(p.name)
        return out

    @property
    def n_positive(self) -> int:
        return int(np.sum(self.labels))

    def subset(self, indices: Sequence[int] | np.ndarray) -> CropSet:
        """The crops at ``indices`` (in that order), sharing nothing with the cache."""
        idx = np.asarray(indices, dtype=np.int64)
        return CropSet(
            paths=tuple(self.paths[i] for i in idx),
            labels=self.labels[idx],
            groups=None if self.groups is None else self.groups[idx],
            root=self.root,
        )

    def load_images(
        self, size: int = 224, *, cache: bool = True, advance: Callable[[int], Any] | None = None
    ) -> np.ndarray:
        """All crops as ``uint8`` BGR ``(n, size, size, 3)``.

        Each image is resized to ``size``×``size`` directly (crops of another aspect ratio are
        stretched, as the classifiers were trained). With ``cache`` the array is kept per size and
        returned read-only on later calls. ``advance(1)`` is called per image (a progress bar).

        Raises:
            InputError: an image cannot be decoded (names it).
        """
        if size < 1:
            raise ValueError(f"size must be >= 1, got {size}")
        if cache and size in self._cache:
            if advance is not None:
                advance(len(self))
            return self._cache[size]
        out = np.empty((len(self), size, size, 3), dtype=np.uint8)
        for i, path in enumerate(self.paths):
            out[i] = _read_resized(path, size)
            if advance is not None:
                advance(1)
        if cache:
            out.flags.writeable = False
            self._cache[size] = out
        return out

    def load_readable(
        self, size: int = 224, *, on_bad: Callable[[InputError], Any]
    ) -> tuple[CropSet, np.ndarray]:
        """The crops that decode, and their images as :meth:`load_images` gives them (not cached).

        For a batch that goes on past a bad file: each crop that cannot be read (corrupt, truncated)
        is handed to ``on_bad`` as the :class:`InputError` naming it, and left out of both results.

        Raises:
            InputError: no crop decodes (names the folder).
        """
        keep: list[int] = []
        images: list[np.ndarray] = []
        for i, path in enumerate(self.paths):
            try:
                images.append(_read_resized(path, size))
            except InputError as exc:
                on_bad(exc)
                continue
            keep.append(i)
        if not keep:
            raise InputError(self.root or Path("."), f"none of its {len(self)} crops can be read")
        return self.subset(keep), np.stack(images)


def _jpeg_problem(data: bytes) -> str | None:
    """What is structurally wrong with JPEG ``data``, or ``None``.

    Walks the marker segments and the entropy-coded scans (ITU-T T.81, B.1) up to the end-of-image
    marker: libjpeg decodes a file cut short without an error (the missing rows grey, a warning on
    stderr), so a truncated crop would otherwise be scored as a real one.
    """
    n = len(data)
    pos = 2  # after the start-of-image marker
    while pos + 1 < n:
        if data[pos] != 0xFF:
            return f"damaged JPEG (no marker at byte {pos})"
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker == 0xD9:  # end of image
            return None
        if marker == 0x01 or 0xD0 <= marker <= 0xD7:  # markers without a length
            pos += 2
            continue
        if pos + 4 > n:
            break
        pos += 2 + int.from_bytes(data[pos + 2 : pos + 4], "big")
        if marker == 0xDA:  # start of scan: entropy-coded data up to the next real marker
            while True:
                pos = data.find(b"\xff", pos)
                if pos < 0 or pos + 1 >= n:
                    return "truncated JPEG (the file ends inside the image data, before its end marker)"
                following = data[pos + 1]
                if following == 0x00 or 0xD0 <= following <= 0xD7:  # stuffed 0xFF or restart marker
                    pos += 2
                elif following == 0xFF:
                    pos += 1
                else:
                    break
    return "truncated JPEG (the file ends before its end-of-image marker)"


def _read_resized(path: Path, size: int) -> np.ndarray:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(path, f"cannot be read ({exc.strerror or exc})") from None
    if data[:2] == b"\xff\xd8" and (problem := _jpeg_problem(data)) is not None:
        raise InputError(path, problem)
    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
    if image is None or image.size == 0:
        raise InputError(path, "OpenCV could not decode this image (corrupt or not an image)")
    h, w = image.shape[:2]
    if (h, w) != (size, size):
        shrink = h > size or w > size
        image = cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    return image


def read_crop_folder(root: str | Path) -> CropSet:
    """Read a crop folder (``images/`` + ``labels.csv``; see the module docstring).

    Every listed image must exist and have a format OpenCV reads (checked from its header; a file
    that is corrupt past the header fails in :meth:`CropSet.load_images`).

    Raises:
        InputError: the folder, ``images/`` or ``labels.csv`` is missing; a required column is
            missing (the message lists those found); a label is not 0/1 or an image name is empty
            or listed twice (with the line number); a listed image is missing or unreadable (names
            it); there are no rows.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(root, "crop folder not found (expected a folder with images/ and labels.csv)")
    images_dir = root / "images"
    csv_path = root / "labels.csv"
    if not images_dir.is_dir():
        raise InputError(images_dir, "missing: a crop folder holds images/ and labels.csv")
    if not csv_path.is_file():
        raise InputError(csv_path, "missing: a crop folder holds images/ and labels.csv (image,emergency)")
    try:
        text = csv_path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(csv_path, f"cannot be read as UTF-8 text ({exc})") from None
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    if header is None:
        raise InputError(csv_path, "empty file; expected the header image,emergency")
    columns = [c.strip().lower() for c in header]
    missing = [c for c in _LABEL_COLUMNS if c not in columns]
    if missing:
        found = ",".join(c for c in columns if c) or "(none)"
        raise InputError(
            csv_path, f"needs columns image,emergency; missing {','.join(missing)}; found: {found}"
        )
    col_image = columns.index("image")
    col_label = columns.index("emergency")
    col_group = columns.index("group") if "group" in columns else None

    paths: list[Path] = []
    labels: list[int] = []
    groups: list[str] = []
    first_line: dict[str, int] = {}
    for row in reader:
        line = reader.line_num
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) < len(columns):
            raise InputError(csv_path, f"line {line}: {len(row)} fields, the header has {len(columns)}")
        name = row[col_image].strip()
        if not name:
            raise InputError(csv_path, f"line {line}: empty image name")
        value = row[col_label].strip()
        if value not in ("0", "1"):
            raise InputError(csv_path, f"line {line}: emergency must be 0 or 1, got {value!r}")
        if name in first_line:
            raise InputError(
                csv_path, f"line {line}: image {name!r} listed twice (first on line {first_line[name]})"
            )
        first_line[name] = line
        if Path(name).is_absolute() or ".." in Path(name).parts or "\x00" in name:
            raise InputError(csv_path, f"line {line}: image name {name!r} does not lie inside images/")
        path = images_dir / name
        try:
            present = path.is_file()
        except OSError as exc:  # a name the file system refuses (too long, ...)
            raise InputError(csv_path, f"line {line}: image name {name[:60]!r} ({exc.strerror})") from None
        if not present:
            raise InputError(path, f"listed in {csv_path.name} (line {line}) but missing")
        if not cv2.haveImageReader(str(path)):
            raise InputError(path, f"listed in {csv_path.name} (line {line}) but not an image OpenCV reads")
        paths.append(path)
        labels.append(int(value))
        if col_group is not None:
            groups.append(row[col_group].strip())
    if not paths:
        raise InputError(csv_path, "no labelled images (the file has a header but no rows)")
    return CropSet(
        paths=tuple(paths),
        labels=np.asarray(labels, dtype=np.int64),
        groups=np.asarray(groups, dtype=str) if col_group is not None else None,
        root=root,
    )


def write_crop_folder(
    out_dir: str | Path,
    items: Iterable[tuple[str, np.ndarray, int, str | None]],
    *,
    jpeg_quality: int = 95,
    advance: Callable[[int], Any] | None = None,
) -> int:
    """Write crops as a crop folder; returns how many were written.

    ``items`` yields ``(name, image_bgr, label, group)``; ``group`` may be ``None`` (then no
    ``group`` column is written unless another item has one). Images go to ``out_dir/images/<name>``
    (format from the suffix); ``labels.csv`` is written last and atomically, so an interrupted run
    leaves no ``labels.csv`` that lists missing images.
    """
    out = Path(out_dir)
    images_dir = out / "images"
    images_dir.mkdir(parents=True, exist_ok=True)
    rows: list[tuple[str, int, str | None]] = []
    seen: set[str] = set()
    for name, image, label, group in items:
        if name in seen:
            raise ValueError(f"crop name {name!r} written twice")
        seen.add(name)
        target = images_dir / name
        params = (
            [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)]
            if target.suffix.lower() in (".jpg", ".jpeg")
            else []
        )
        with atomic_path(target) as tmp:
            if not cv2.imwrite(str(tmp), image, params):
                raise OSError(f"{target}: OpenCV could not write this image")
        rows.append((name, int(label), group))
        if advance is not None:
            advance(1)
    with_group = any(g is not None for _, _, g in rows)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["image", "emergency", "group"] if with_group else ["image", "emergency"])
    for name, label, group in rows:
        writer.writerow([name, label, group or ""] if with_group else [name, label])
    write_text_atomic(out / "labels.csv", buf.getvalue())
    return len(rows)


_ROBOFLOW = re.compile(r"\.rf\.[0-9a-fA-F]+$")


def roboflow_source(stem: str) -> str:
    """The source photo of a Roboflow export file stem: ``0002_jpg.rf.c61e…`` → ``0002_jpg``.

    Roboflow writes augmented copies of one photo as ``<photo>_<ext>.rf.<hash>``; copies share the
    source. Stems without the pattern are returned unchanged.
    """
    return _ROBOFLOW.sub("", stem)


# ----------------------------------------------------------------------------------------------- YOLO


@dataclass(frozen=True, slots=True)
class YoloImage:
    """One image of a YOLO detection set with its boxes in pixels (see :class:`~makeway.messages.Box`)."""

    path: Path
    width: int
    height: int
    boxes: tuple[Box, ...]
    class_ids: tuple[int, ...]
    label_path: Path | None = None

    def boxes_of(self, class_id: int) -> list[Box]:
        """The boxes of one class."""
        return [b for b, c in zip(self.boxes, self.class_ids, strict=True) if c == class_id]


_COORD_TOL = 1e-3  # exporters round; accept coordinates a hair outside [0, 1]


def _parse_yolo_label(label_path: Path, width: int, height: int) -> tuple[list[Box], list[int]]:
    try:
        text = label_path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(label_path, f"cannot be read as text ({exc})") from None
    boxes: list[Box] = []
    class_ids: list[int] = []
    for line_no, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        if not fields:
            continue
        if len(fields) != 5:
            raise InputError(
                label_path, f"line {line_no}: expected 5 fields 'cls cx cy w h', found {len(fields)}"
            )
        try:
            cls = int(fields[0])
            cx, cy, w, h = (float(v) for v in fields[1:])
        except ValueError:
            raise InputError(
                label_path, f"line {line_no}: expected an integer class and 4 numbers, got {line.strip()!r}"
            ) from None
        if cls < 0:
            raise InputError(label_path, f"line {line_no}: class must be >= 0, got {cls}")
        vals = np.array([cx, cy, w, h])
        if not np.all(np.isfinite(vals)) or np.any(vals < -_COORD_TOL) or np.any(vals > 1 + _COORD_TOL):
            raise InputError(
                label_path, f"line {line_no}: cx cy w h must be normalised to [0, 1], got {line.strip()!r}"
            )
        if w <= 0 or h <= 0:
            raise InputError(label_path, f"line {line_no}: box width and height must be > 0")
        box = Box((cx - w / 2) * width, (cy - h / 2) * height, (cx + w / 2) * width, (cy + h / 2) * height)
        boxes.append(box.clip(width, height))
        class_ids.append(cls)
    return boxes, class_ids


def read_yolo_set(root: str | Path) -> list[YoloImage]:
    """Read a YOLO detection set (``images/`` + ``labels/``), sorted by image name.

    Image sizes come from decoding each image (needed to turn normalised boxes into pixels).

    Raises:
        InputError: a folder is missing or holds no images; an image cannot be decoded; a label line
            is malformed (file and line number).
    """
    root = Path(root)
    images_dir, labels_dir = root / "images", root / "labels"
    if not images_dir.is_dir():
        raise InputError(images_dir, "missing: a YOLO set holds images/ and labels/")
    if not labels_dir.is_dir():
        raise InputError(labels_dir, "missing: a YOLO set holds images/ and labels/")
    image_paths = sorted(
        p for p in images_dir.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES
    )
    if not image_paths:
        raise InputError(images_dir, f"no images ({', '.join(IMAGE_SUFFIXES)})")
    out: list[YoloImage] = []
    for path in image_paths:
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None or image.size == 0:
            raise InputError(path, "OpenCV could not decode this image")
        height, width = image.shape[:2]
        label_path = labels_dir / f"{path.stem}.txt"
        if label_path.is_file():
            boxes, class_ids = _parse_yolo_label(label_path, width, height)
            lp: Path | None = label_path
        else:
            boxes, class_ids, lp = [], [], None
        out.append(YoloImage(path, int(width), int(height), tuple(boxes), tuple(class_ids), lp))
    return out


# ------------------------------------------------------------------------------ near duplicates, split


def _grey_thumbnails(images: np.ndarray, side: int) -> np.ndarray:
    images = np.asarray(images)
    if images.ndim not in (3, 4) or images.shape[0] == 0:
        raise ValueError(f"expected images (n, H, W[, 3]), got shape {images.shape}")
    out = np.empty((images.shape[0], side, side), dtype=np.float32)
    for i, image in enumerate(images):
        grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
        out[i] = cv2.resize(grey, (side, side), interpolation=cv2.INTER_AREA)
    return out


def average_hash(images: np.ndarray) -> np.ndarray:
    """The 64-bit average hash of each image: ``(n, 64)`` bool (grey, 8×8 area-resize, > mean)."""
    thumbs = _grey_thumbnails(images, 8).reshape(len(images), 64)
    return thumbs > thumbs.mean(axis=1, keepdims=True)


def thumbnail_signatures(images: np.ndarray, side: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """Zero-mean, unit-norm grey ``side``×``side`` thumbnails, as is and mirrored left-right.

    The dot product of two signatures is the Pearson correlation of the thumbnails.
    """
    thumbs = _grey_thumbnails(images, side)

    def norm(t: np.ndarray) -> np.ndarray:
        v = t.reshape(len(t), -1).astype(np.float64)
        v -= v.mean(axis=1, keepdims=True)
        v /= np.linalg.norm(v, axis=1, keepdims=True) + 1e-9
        return v

    return norm(thumbs), norm(thumbs[:, :, ::-1])


def _near_duplicate_links(images: np.ndarray, others: np.ndarray, min_correlation: float) -> np.ndarray:
    """``(n, m)`` bool: image i of ``images`` and image j of ``others`` are near-duplicates (the rule
    of :func:`near_duplicate_groups`)."""
    sig, mirrored = thumbnail_signatures(images)
    other_sig, _ = thumbnail_signatures(others)
    corr = np.maximum(sig @ other_sig.T, mirrored @ other_sig.T)
    a = average_hash(images).astype(np.float64)
    b = average_hash(others).astype(np.float64)
    same_hash = (a @ b.T + (1 - a) @ (1 - b).T) >= 64
    linked: np.ndarray = (corr >= min_correlation) | same_hash
    return linked


def near_duplicate_groups(images: np.ndarray, *, min_correlation: float = 0.85) -> np.ndarray:
    """Cluster ids ``(n,)`` that put near-duplicate images together.

    Two images are linked when their grey 32×32 thumbnails correlate at ``min_correlation`` or
    more (one of them possibly mirrored) or their 8×8 average hashes are identical; clusters are
    the connected components of the links. On ``ev_crops`` exact copies correlate above 0.99 and
    shots of one scene above ~0.85 while unrelated crops stay below (the 8×8 average hash alone
    links unrelated crops from a Hamming distance of 2 on); 0.85 keeps the largest cluster at 7.
    O(n²) memory in float64: fine for a few thousand crops.
    """
    linked = _near_duplicate_links(images, images, min_correlation)
    i, j = np.nonzero(linked)
    graph = coo_matrix((np.ones(len(i), dtype=np.int8), (i, j)), shape=(len(images), len(images)))
    _, ids = connected_components(graph, directed=False)
    return ids.astype(np.int64)


def near_duplicates_of(
    images: np.ndarray, reference: np.ndarray, *, min_correlation: float = 0.85
) -> np.ndarray:
    """``(n,)`` bool: which of ``images`` is a near-duplicate of some image of ``reference`` (the
    rule of :func:`near_duplicate_groups`), e.g. pool crops that copy a held-out crop."""
    if len(images) == 0 or len(reference) == 0:
        return np.zeros(len(images), dtype=bool)
    return np.asarray(_near_duplicate_links(images, reference, min_correlation).any(axis=1), dtype=bool)


def split_holdout(
    crop_set: CropSet,
    fraction: float = 0.2,
    seed: int = 0,
    groups: Sequence[Any] | np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Split into ``(train_idx, test_idx)`` (sorted ``int64``) with about ``fraction`` held out.

    Groups never straddle: ``groups`` if given, else ``crop_set.groups``, else near-duplicate
    clusters (:func:`near_duplicate_groups` on 64×64 loads). Stratified by label: each group counts
    towards its majority label, and groups of each label are drawn in a seeded random order until
    that label's held-out share reaches ``fraction``.
    """
    if not 0.0 < fraction < 1.0:
        raise ValueError(f"fraction must be in (0, 1), got {fraction}")
    n = len(crop_set)
    if groups is None:
        groups = crop_set.groups
    if groups is None:
        group_ids = near_duplicate_groups(crop_set.load_images(64, cache=False))
    else:
        groups = np.asarray(groups)
        if len(groups) != n:
            raise ValueError(f"{len(groups)} groups for {n} crops")
        _, group_ids = np.unique(groups, return_inverse=True)
    group_ids = np.asarray(group_ids).ravel()
    n_groups = int(group_ids.max()) + 1
    size = np.bincount(group_ids, minlength=n_groups)
    pos = np.bincount(group_ids, weights=crop_set.labels.astype(np.float64), minlength=n_groups)
    group_label = (2 * pos >= size).astype(np.int64)
    rng = np.random.default_rng(seed)
    in_test = np.zeros(n_groups, dtype=bool)
    for label in (0, 1):
        ids = np.flatnonzero((group_label == label) & (size > 0))
        target = fraction * size[ids].sum()
        taken = 0
        for g in rng.permutation(ids):
            if taken >= target:
                break
            in_test[g] = True
            taken += size[g]
    test = np.flatnonzero(in_test[group_ids])
    train = np.flatnonzero(~in_test[group_ids])
    if len(test) == 0 or len(train) == 0:
        raise ValueError(f"cannot split {n} crops in {n_groups} groups with fraction {fraction}")
    return train.astype(np.int64), test.astype(np.int64)


# ------------------------------------------------------------------------------------- holdout file


def names_fingerprint(names: Iterable[str]) -> str:
    """SHA-256 (hex, first 16 chars) of the sorted image names: identifies a crop set's membership."""
    joined = "\n".join(sorted(names)).encode("utf-8")
    return hashlib.sha256(joined).hexdigest()[:16]


@dataclass(frozen=True)
class Holdout:
    """A committed held-out part: image names plus the ``# key: value`` header of its file."""

    names: tuple[str, ...]
    meta: Mapping[str, str]
    path: Path | None = None

    def matches(self, crop_set: CropSet) -> bool:
        """Whether this holdout was made from ``crop_set`` (same image names)."""
        return self.meta.get("set_fingerprint") == names_fingerprint(crop_set.names)


def write_holdout(
    path: str | Path,
    crop_set: CropSet,
    test_idx: Sequence[int] | np.ndarray,
    *,
    meta: Mapping[str, Any] | None = None,
) -> None:
    """Write the held-out image names (sorted, one a line) after a ``# key: value`` header."""
    idx = np.asarray(test_idx, dtype=np.int64)
    names = crop_set.names
    held = sorted(names[i] for i in idx)
    header = {
        "what": "held-out crops: never train or tune on these",
        "set_fingerprint": names_fingerprint(names),
        "set_size": str(len(names)),
        "held_out": str(len(held)),
        "held_out_positive": str(int(crop_set.labels[idx].sum())),
    }
    header.update({k: str(v) for k, v in (meta or {}).items()})
    lines = [f"# {k}: {v}" for k, v in header.items()]
    write_text_atomic(path, "\n".join([*lines, *held]) + "\n")


def read_holdout(path: str | Path = EV_CROPS_HOLDOUT) -> Holdout:
    """Read a holdout file written by :func:`write_holdout`.

    Raises:
        InputError: the file is missing or lists no names.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot read the holdout file ({exc})") from None
    meta: dict[str, str] = {}
    names: list[str] = []
    for line in text.splitlines():
        if line.startswith("#"):
            key, _, value = line[1:].partition(":")
            meta[key.strip()] = value.strip()
        elif line.strip():
            names.append(line.strip())
    if not names:
        raise InputError(path, "lists no image names")
    return Holdout(tuple(names), meta, path)


def holdout_split(crop_set: CropSet, holdout: Holdout) -> tuple[np.ndarray, np.ndarray]:
    """``(train_idx, test_idx)`` of ``crop_set`` for a committed holdout.

    Raises:
        InputError: a held-out name is not in the set (the holdout belongs to another set).
    """
    index = {name: i for i, name in enumerate(crop_set.names)}
    missing = [n for n in holdout.names if n not in index]
    if missing:
        where = holdout.path if holdout.path is not None else Path("holdout")
        raise InputError(
            where, f"{len(missing)} held-out images are not in this crop set (e.g. {missing[0]!r})"
        )
    test = np.sort(np.asarray([index[n] for n in holdout.names], dtype=np.int64))
    mask = np.ones(len(crop_set), dtype=bool)
    mask[test] = False
    return np.flatnonzero(mask).astype(np.int64), test


def committed_split(crop_set: CropSet) -> tuple[np.ndarray, np.ndarray] | None:
    """``(train_idx, test_idx)`` of ``crop_set`` when it is the set the committed holdout
    (:data:`EV_CROPS_HOLDOUT`, the ev_crops held-out names) was made for; ``None`` for any other set."""
    if not EV_CROPS_HOLDOUT.is_file():
        return None
    committed = read_holdout(EV_CROPS_HOLDOUT)
    if not committed.matches(crop_set):
        return None
    return holdout_split(crop_set, committed)


def ambulance_held_out_split(crop_set: CropSet) -> tuple[np.ndarray, np.ndarray] | None:
    """``(train_idx, test_idx)`` of a crop folder built from ``ambulance_yolo``: the test part holds
    the crops of the source photos listed in :data:`AMBULANCE_YOLO_HELD_OUT`. ``None`` for any other
    set — one without groups, with a crop whose name does not start with its group's photo
    (``<group>.rf.``), or with no crop of a held-out photo."""
    if crop_set.groups is None or not AMBULANCE_YOLO_HELD_OUT.is_file() or not len(crop_set):
        return None
    groups = np.asarray(crop_set.groups).astype(str)
    if not all(p.name.startswith(f"{g}.rf.") for p, g in zip(crop_set.paths, groups, strict=True)):
        return None
    lines = AMBULANCE_YOLO_HELD_OUT.read_text(encoding="utf-8").splitlines()
    held = {roboflow_source(Path(n.strip()).stem) for n in lines if n.strip() and not n.startswith("#")}
    test = np.isin(groups, sorted(held))
    if not test.any():
        return None
    return np.flatnonzero(~test).astype(np.int64), np.flatnonzero(test).astype(np.int64)


def training_split(crop_set: CropSet) -> tuple[np.ndarray, np.ndarray] | None:
    """The committed ``(train_idx, test_idx)`` of ``crop_set``: the ``ev_crops`` holdout
    (:func:`committed_split`) or the held-out photos of the ``ambulance_yolo`` crops
    (:func:`ambulance_held_out_split`); ``None`` for any other set (trained on whole)."""
    split = committed_split(crop_set)
    return split if split is not None else ambulance_held_out_split(crop_set)
