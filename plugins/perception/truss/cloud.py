"""Point-cloud preparation for truss modelling: pose transform, voxel accumulation, normals."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from daemon.messages import BodyState


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


def neighbourhoods(points: np.ndarray, k: int) -> tuple[cKDTree, np.ndarray, np.ndarray]:
    """KD-tree of the cloud, and each point's k nearest neighbours (distances, indices)."""
    tree = cKDTree(points)
    distances, indices = tree.query(points, k=min(k, len(points)))
    return tree, distances, indices


def estimate_normals(points: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Unit normals (unoriented) from the smallest principal direction of each neighbourhood."""
    patch = points[indices] - points[indices].mean(axis=1, keepdims=True)
    covariance = np.einsum("nki,nkj->nij", patch, patch)
    _, vectors = np.linalg.eigh(covariance)
    return vectors[:, :, 0]
