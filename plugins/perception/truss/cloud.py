"""Point-cloud preparation for truss modelling: pose transform, voxel accumulation, normals."""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.spatial.transform import Rotation

from climbd.daemon.contract.messages import BodyState


def body_to_odometry(points: np.ndarray, body: BodyState) -> np.ndarray:
    """Body-frame points (N, 3) into the odometry frame with the body pose (quaternion w,x,y,z)."""
    rotation = Rotation.from_quat(body.orientation, scalar_first=True).as_matrix()
    return points @ rotation.T + np.asarray(body.position, dtype=float)


def _voxel_keys(points: np.ndarray, voxel: float) -> np.ndarray:
    cells = np.floor(points / voxel).astype(np.int64) + (1 << 20)
    return (cells[:, 0] << 42) | (cells[:, 1] << 21) | cells[:, 2]


def voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """One point per occupied voxel: the centroid of the points in it (the cloud's resolution)."""
    _, inverse, counts = np.unique(
        _voxel_keys(points, voxel), return_inverse=True, return_counts=True
    )
    return _sums(inverse, points, len(counts)) / counts[:, None]


def _sums(inverse: np.ndarray, values: np.ndarray, bins: int) -> np.ndarray:
    """Per-bin sums of the rows of ``values`` (N x 3) given each row's bin."""
    return np.column_stack([np.bincount(inverse, values[:, k], bins) for k in range(3)])


class VoxelMap:
    """A dense cloud accumulated over frames as per-voxel centroids (bounded by the voxel count)."""

    def __init__(self, voxel: float) -> None:
        self.voxel = voxel
        self._keys = np.empty(0, np.int64)
        self._sums = np.empty((0, 3))
        self._counts = np.empty(0, np.int64)

    def __len__(self) -> int:
        return len(self._keys)

    def add(self, points: np.ndarray) -> None:
        """Fold odometry-frame points into the map."""
        keys = np.concatenate([self._keys, _voxel_keys(points, self.voxel)])
        uniq, inverse = np.unique(keys, return_inverse=True)
        values = np.concatenate([self._sums, points])
        weights = np.concatenate([self._counts, np.ones(len(points), np.int64)])
        self._sums = _sums(inverse, values, len(uniq))
        self._counts = np.bincount(inverse, weights, len(uniq)).astype(np.int64)
        self._keys = uniq

    @property
    def points(self) -> np.ndarray:
        return self._sums / self._counts[:, None]


def _ball_offsets(reach: float) -> np.ndarray:
    """Packed key offsets of the voxels whose centres lie within ``reach`` voxels of a voxel's."""
    span = np.arange(-int(reach), int(reach) + 1)
    d = np.stack(np.meshgrid(span, span, span, indexing="ij"), -1).reshape(-1, 3)
    d = d[(d * d).sum(axis=1) <= reach * reach]
    return (d[:, 0] << 42) + (d[:, 1] << 21) + d[:, 2]


def ball_normals(points: np.ndarray, voxel: float, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """Normals of a voxel-downsampled cloud (one point per voxel) from the points in the voxels
    within ``reach`` voxels of each point's, and how many other points that ball holds.

    A look-up of the voxel keys instead of a KD-tree query (one point per voxel, so the
    neighbourhood is a fixed set of voxels), of half the ball's offsets: voxel b lies in a's
    ball as a lies in b's, so the pairs found (a sparse upper matrix U) give the ball sums of
    the moments as m + U m + U^T m.
    """
    keys = _voxel_keys(points, voxel)
    order = np.argsort(keys)
    keys = keys[order]
    offsets = _ball_offsets(reach)
    query = keys + offsets[offsets > 0][:, None]  # rows ascending: a near-linear search
    slot = np.minimum(np.searchsorted(keys, query), len(keys) - 1)
    hit = (keys[slot] == query).T
    pairs = hit.sum(axis=1)
    partner = slot.T[hit]
    upper = sparse.csr_matrix(
        (np.ones(len(partner)), partner, np.concatenate([[0], np.cumsum(pairs)])),
        shape=(len(keys), len(keys)),
    )
    x, y, z = (points[order] - points.mean(axis=0)).T
    own = np.column_stack([x, y, z, x * x, x * y, x * z, y * y, y * z, z * z])
    sums = own + upper @ own + upper.T @ own
    count = 1 + pairs + np.bincount(partner, minlength=len(keys))
    moments = _covariances(list(sums[:, 3:].T), count, sums[:, :3] / count[:, None])
    normals, neighbours = np.empty_like(points), np.empty_like(count)
    normals[order], neighbours[order] = smallest_eigenvectors(moments), count - 1
    return normals, neighbours


def voxel_normals(points: np.ndarray, voxel: float, min_points: int = 3) -> tuple:
    """Centroid and normal of every voxel holding at least ``min_points`` points: a coarse
    oriented cloud (for plane candidates) in one pass of per-voxel moments, no neighbour search."""
    _, inverse, counts = np.unique(
        _voxel_keys(points, voxel), return_inverse=True, return_counts=True
    )
    bins = len(counts)
    centroids = _sums(inverse, points, bins) / counts[:, None]
    x, y, z = points.T
    products = [
        np.bincount(inverse, a * b, bins)
        for a, b in ((x, x), (x, y), (x, z), (y, y), (y, z), (z, z))
    ]
    full = counts >= min_points
    moments = _covariances([p[full] for p in products], counts[full], centroids[full])
    return centroids[full], smallest_eigenvectors(moments)


def _covariances(products: list, count: np.ndarray, centroids: np.ndarray) -> np.ndarray:
    """3 x 3 scatter matrices about the centroids from the sums of xx, xy, xz, yy, yz, zz."""
    xx, xy, xz, yy, yz, zz = products
    cx, cy, cz = centroids.T
    a = np.empty((len(count), 3, 3))
    a[:, 0, 0] = xx - count * cx * cx
    a[:, 0, 1] = a[:, 1, 0] = xy - count * cx * cy
    a[:, 0, 2] = a[:, 2, 0] = xz - count * cx * cz
    a[:, 1, 1] = yy - count * cy * cy
    a[:, 1, 2] = a[:, 2, 1] = yz - count * cy * cz
    a[:, 2, 2] = zz - count * cz * cz
    return a


def smallest_eigenvectors(a: np.ndarray) -> np.ndarray:
    """Unit eigenvectors of the smallest eigenvalues of symmetric 3x3 matrices (N, 3, 3).

    Closed form (trigonometric eigenvalues, then the widest cross product of two rows of
    A - lambda I): several times faster than ``np.linalg.eigh`` on many small matrices.
    """
    a00, a01, a02 = a[:, 0, 0], a[:, 0, 1], a[:, 0, 2]
    a11, a12, a22 = a[:, 1, 1], a[:, 1, 2], a[:, 2, 2]
    q = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p = np.sqrt((b00**2 + b11**2 + b22**2 + 2.0 * (a01**2 + a02**2 + a12**2)) / 6.0)
    det = (
        b00 * (b11 * b22 - a12 * a12)
        - a01 * (a01 * b22 - a12 * a02)
        + a02 * (a01 * a12 - b11 * a02)
    )
    r = np.clip(det / (2.0 * np.where(p > 0, p, 1.0) ** 3), -1.0, 1.0)
    smallest = q + 2.0 * p * np.cos(np.arccos(r) / 3.0 + 2.0 * np.pi / 3.0)
    c00, c11, c22 = a00 - smallest, a11 - smallest, a22 - smallest
    # cross products of the rows (c00, a01, a02), (a01, c11, a12), (a02, a12, c22)
    candidates = np.stack(
        [
            np.stack([a01 * a12 - a02 * c11, a02 * a01 - c00 * a12, c00 * c11 - a01 * a01], 1),
            np.stack([a01 * c22 - a02 * a12, a02 * a02 - c00 * c22, c00 * a12 - a01 * a02], 1),
            np.stack([c11 * c22 - a12 * a12, a12 * a02 - a01 * c22, a01 * a12 - c11 * a02], 1),
        ],
        axis=1,
    )
    lengths = np.einsum("nij,nij->ni", candidates, candidates)
    pick = lengths.argmax(axis=1)
    best = candidates[np.arange(len(a)), pick]
    norm = np.sqrt(lengths[np.arange(len(a)), pick])
    ok = norm > 1e-30
    return np.where(ok[:, None], best / np.where(ok, norm, 1.0)[:, None], [0.0, 0.0, 1.0])
