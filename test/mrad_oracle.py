"""Slow, obviously-right float64 reference implementations used as test oracles.

Nothing here is optimised: every pixel gets its own Mahalanobis distances computed with
``numpy.linalg.solve`` on the regularised covariance of its cell.
"""

from __future__ import annotations

import numpy as np

_SCALE = {np.dtype(np.uint8): 1.0, np.dtype(np.uint16): 255.0 / 65535.0}


def to_255(image: np.ndarray) -> np.ndarray:
    return image.astype(np.float64) * _SCALE.get(image.dtype, 255.0)


def edges(length: int, grid: int) -> list[int]:
    return [int(np.floor(i * length / grid + 0.5)) for i in range(grid + 1)]


def cell_of(row: int, col: int, height: int, width: int, grid: int) -> tuple[int, int]:
    rows, cols = edges(height, grid), edges(width, grid)
    i = max(k for k in range(grid) if rows[k] <= row)
    j = max(k for k in range(grid) if cols[k] <= col)
    return i, j


def cell_pixels(image: np.ndarray, i: int, j: int, grid: int) -> np.ndarray:
    rows, cols = edges(image.shape[0], grid), edges(image.shape[1], grid)
    return image[rows[i] : rows[i + 1], cols[j] : cols[j + 1]].reshape(-1, 3)


def regularised_cov(pixels: np.ndarray, abs_floor: float, rel_floor: float) -> np.ndarray:
    cov = np.cov(pixels.T, ddof=1) if len(pixels) > 1 else np.zeros((3, 3))
    lam = max(abs_floor, rel_floor * np.trace(cov) / 3.0)
    return cov + lam * np.eye(3)


def mahalanobis_sq(x: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> float:
    d = x - mean
    return float(d @ np.linalg.solve(cov, d))


def cross_score_terms(
    query: np.ndarray, reference: np.ndarray, grid: int, abs_floor: float, rel_floor: float
) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel loop: the reference term and the query term of the cross score."""
    q, r = to_255(query), to_255(reference)
    height, width = q.shape[:2]
    models = {}
    for i in range(grid):
        for j in range(grid):
            rp, qp = cell_pixels(r, i, j, grid), cell_pixels(q, i, j, grid)
            models[i, j] = (
                rp.mean(axis=0),
                regularised_cov(rp, abs_floor, rel_floor),
                qp.mean(axis=0),
                regularised_cov(qp, abs_floor, rel_floor),
            )
    t0 = np.zeros((height, width))
    t1 = np.zeros((height, width))
    for row in range(height):
        for col in range(width):
            mu0, s0, mu1, s1 = models[cell_of(row, col, height, width, grid)]
            t0[row, col] = mahalanobis_sq(q[row, col], mu0, s0)
            t1[row, col] = mahalanobis_sq(q[row, col], mu1, s1)
    return t0, t1


def cross_score_vectorised(
    query: np.ndarray, reference: np.ndarray, grid: int, abs_floor: float, rel_floor: float
) -> np.ndarray:
    """The same score, per pixel in float64, vectorised per cell with einsum (benchmark)."""
    q, r = to_255(query), to_255(reference)
    out = np.empty(q.shape[:2])
    qr, qc = edges(q.shape[0], grid), edges(q.shape[1], grid)
    for i in range(grid):
        for j in range(grid):
            rp, qp = cell_pixels(r, i, j, grid), cell_pixels(q, i, j, grid)
            p0 = np.linalg.inv(regularised_cov(rp, abs_floor, rel_floor))
            p1 = np.linalg.inv(regularised_cov(qp, abs_floor, rel_floor))
            d0, d1 = qp - rp.mean(axis=0), qp - qp.mean(axis=0)
            score = np.einsum("ni,ij,nj->n", d0, p0, d0) - np.einsum("ni,ij,nj->n", d1, p1, d1)
            out[qr[i] : qr[i + 1], qc[j] : qc[j + 1]] = score.reshape(
                qr[i + 1] - qr[i], qc[j + 1] - qc[j]
            )
    return out


def local_std_naive(scores: np.ndarray, window: tuple[int, int]) -> np.ndarray:
    """Standard deviation of the (reflect-padded) window around each pixel."""
    kh, kw = window
    top, left = kh // 2, kw // 2
    padded = np.pad(
        scores.astype(np.float64), ((top, kh - 1 - top), (left, kw - 1 - left)), "symmetric"
    )
    out = np.empty(scores.shape)
    for row in range(scores.shape[0]):
        for col in range(scores.shape[1]):
            out[row, col] = padded[row : row + kh, col : col + kw].std()
    return out


def flood_fill_naive(
    values: np.ndarray, seed: tuple[int, int], tolerance: float, floor: float
) -> np.ndarray:
    """Breadth-first region growing, 8-connected, fixed range around the seed's value."""
    height, width = values.shape
    centre = values[seed]
    region = np.zeros(values.shape, dtype=bool)
    stack = [seed]
    while stack:
        row, col = stack.pop()
        if region[row, col]:
            continue
        v = values[row, col]
        if v < floor or abs(v - centre) > tolerance:
            continue
        region[row, col] = True
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                r, c = row + dr, col + dc
                if 0 <= r < height and 0 <= c < width and not region[r, c]:
                    stack.append((r, c))
    return region


def structure_score_naive(
    query: np.ndarray,
    reference: np.ndarray,
    grid: int,
    dark_floor: float = 8.0,
    near: int = 2,
    noise_sigmas: float = 3.0,
) -> np.ndarray:
    """The structure cue per pixel in float64, for images of the same size.

    ``e = |grad log(luma + dark_floor)|`` with explicit 3 x 3 Sobel sums over 8 at
    reflect-101 borders; ``d = e_q - max(e_r over the (2 near + 1) square inside the
    image)``; per cell ``max(0, d - max(0, median(d) + noise_sigmas * 1.4826 * MAD(d)))``.
    """

    def channel(image: np.ndarray) -> np.ndarray:
        rgb = to_255(image)
        luma = rgb[..., 0] * 0.299 + rgb[..., 1] * 0.587 + rgb[..., 2] * 0.114
        values = np.log(luma + dark_floor)
        height, width = values.shape

        def at(row: int, col: int) -> float:
            # reflect-101: -1 -> 1, n -> n - 2
            row = -row if row < 0 else (2 * (height - 1) - row if row >= height else row)
            col = -col if col < 0 else (2 * (width - 1) - col if col >= width else col)
            return float(values[row, col])

        out = np.empty((height, width))
        for row in range(height):
            for col in range(width):
                gx = gy = 0.0
                for d, w in ((-1, 1.0), (0, 2.0), (1, 1.0)):
                    gx += w * (at(row + d, col + 1) - at(row + d, col - 1))
                    gy += w * (at(row + 1, col + d) - at(row - 1, col + d))
                out[row, col] = np.hypot(gx / 8.0, gy / 8.0)
        return out

    q, r = channel(query), channel(reference)
    height, width = q.shape
    excess = np.empty((height, width))
    for row in range(height):
        for col in range(width):
            near_ref = r[
                max(0, row - near) : row + near + 1, max(0, col - near) : col + near + 1
            ].max()
            excess[row, col] = q[row, col] - near_ref
    rows, cols = edges(height, grid), edges(width, grid)
    out = np.zeros((height, width))
    for i in range(grid):
        for j in range(grid):
            cell = excess[rows[i] : rows[i + 1], cols[j] : cols[j + 1]]
            centre = np.median(cell)
            level = max(0.0, centre + noise_sigmas * 1.4826 * np.median(np.abs(cell - centre)))
            out[rows[i] : rows[i + 1], cols[j] : cols[j + 1]] = np.maximum(cell - level, 0.0)
    return out


def _lower_median(values: list[float]) -> float:
    ordered = sorted(values)
    return ordered[(len(ordered) - 1) // 2] if ordered else 0.0


def _window_pixels(image: np.ndarray, row: int, col: int, radius: int) -> np.ndarray:
    # The square of side 2 radius + 1 around (row, col), clipped at the image's border.
    return image[
        max(0, row - radius) : row + radius + 1, max(0, col - radius) : col + radius + 1
    ].reshape(-1, image.shape[2] if image.ndim == 3 else 1)


def colour_evidence_naive(
    query: np.ndarray,
    reference: np.ndarray,
    grid: int,
    radius: int,
    abs_floor: float = 16.0,
    noise_sigmas: float = 3.0,
) -> np.ndarray:
    """The local colour cue per pixel in float64, for uint8 images of the same size.

    Per pixel: the per-channel min and max of the reference within the clipped square of
    side ``2 radius + 1``; ``d`` the largest per-channel excess of the query beyond them.
    Per cell: ``sigma = max(sqrt(abs_floor), 1.4826 * lower median of d)``; the evidence is
    ``(d / sigma)^2`` where ``d > noise_sigmas * sigma``, else 0.
    """
    q, r = query.astype(np.float64), reference.astype(np.float64)
    height, width = q.shape[:2]
    distance = np.zeros((height, width))
    for row in range(height):
        for col in range(width):
            near = _window_pixels(r, row, col, radius)
            low, high = near.min(axis=0), near.max(axis=0)
            excess = [
                max(0.0, q[row, col, c] - high[c]) + max(0.0, low[c] - q[row, col, c])
                for c in range(3)
            ]
            distance[row, col] = max(excess)
    rows, cols = edges(height, grid), edges(width, grid)
    out = np.zeros((height, width))
    for i in range(grid):
        for j in range(grid):
            cell = distance[rows[i] : rows[i + 1], cols[j] : cols[j + 1]]
            sigma = max(np.sqrt(abs_floor), 1.4826 * _lower_median(list(cell.ravel())))
            for (a, b), d in np.ndenumerate(cell):
                if d > noise_sigmas * sigma:
                    out[rows[i] + a, cols[j] + b] = (d / sigma) ** 2
    return out


def grey_naive(image: np.ndarray) -> np.ndarray:
    """The integer BT.601 grey of a uint8 RGB image, as OpenCV rounds it: ``(9798 R + 19235 G
    + 3735 B + 16384) >> 15`` (0.299, 0.587, 0.114 in 15 fixed-point bits)."""
    out = np.zeros(image.shape[:2], np.int64)
    for (row, col), _ in np.ndenumerate(out):
        red, green, blue = (int(v) for v in image[row, col])
        out[row, col] = (9798 * red + 19235 * green + 3735 * blue + 16384) >> 15
    return out


def dark_evidence_naive(
    query: np.ndarray,
    reference: np.ndarray,
    grid: int,
    radius: int,
    abs_floor: float = 16.0,
    dark_floor: float = 8.0,
    space_level: float = 8.0,
    noise_sigmas: float = 3.0,
) -> np.ndarray:
    """The local dark cue per pixel in float64, for uint8 images of the same size.

    ``low`` the smallest reference grey within the clipped square; a pixel is lit when
    ``low > space_level``; ``share = rint(255 (low - q) / (low + dark_floor))`` where
    ``low - q > noise_sigmas * sqrt(abs_floor)``, else 0. Per cell, the lower median ``m``
    of the lit pixels' shares (0 for none); the evidence is ``(share - m) / 255`` at lit
    pixels where positive, else 0.
    """
    q, r = grey_naive(query).astype(np.float64), grey_naive(reference).astype(np.float64)
    height, width = q.shape
    share = np.zeros((height, width))
    lit = np.zeros((height, width), bool)
    for row in range(height):
        for col in range(width):
            low = _window_pixels(r[..., None], row, col, radius).min()
            lit[row, col] = low > space_level
            hidden = low - q[row, col]
            if hidden > noise_sigmas * np.sqrt(abs_floor):
                share[row, col] = np.rint(255.0 * hidden / (low + dark_floor))
    rows, cols = edges(height, grid), edges(width, grid)
    out = np.zeros((height, width))
    for i in range(grid):
        for j in range(grid):
            block = (slice(rows[i], rows[i + 1]), slice(cols[j], cols[j + 1]))
            median = _lower_median(list(share[block][lit[block]]))
            for (a, b), value in np.ndenumerate(share[block]):
                if lit[block][a, b] and value > median:
                    out[rows[i] + a, cols[j] + b] = (value - median) / 255.0
    return out


def components_naive(clipped: np.ndarray) -> list[list[tuple[int, int]]]:
    """The 8-connected components of a boolean image by a flood fill, pixel by pixel."""
    seen = np.zeros_like(clipped)
    found = []
    for start in zip(*np.nonzero(clipped), strict=True):
        if seen[start]:
            continue
        seen[start] = True
        stack, pixels = [start], []
        while stack:
            row, col = stack.pop()
            pixels.append((row, col))
            for dr in (-1, 0, 1):
                for dc in (-1, 0, 1):
                    r, c = row + dr, col + dc
                    inside = 0 <= r < clipped.shape[0] and 0 <= c < clipped.shape[1]
                    if inside and clipped[r, c] and not seen[r, c]:
                        seen[r, c] = True
                        stack.append((r, c))
        found.append(pixels)
    return found
