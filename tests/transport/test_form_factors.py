"""Monte Carlo form factors against analytic view factors (Howell's catalogue C-11, C-14).

Tolerance: 4 binomial standard errors sqrt(F (1 - F) / N) of the analytic F, plus DISC for the
discretisation of each patch into its candidate origins (quad centres, a midpoint rule).
"""

import math

import numpy as np
import pytest
import torch

from torchrefl.core.rays import RayTracer
from torchrefl.core.surface import Surface
from torchrefl.errors import ConfigError, GeometryError
from torchrefl.geometry.range_mesh import grid_triangulation
from torchrefl.transport.form_factors import form_factors_for_surface, hemisphere_form_factors, sampling_error
from torchrefl.transport.patches import face_patches, texel_patches

DISC = 5e-4
OFFSET = 1e-5


def perpendicular(w, h, l):
    """Howell C-14: F from a w x l rectangle to an h x l rectangle at 90 degrees sharing the l edge."""
    W, H = w / l, h / l
    S = W * W + H * H
    t = W * math.atan(1 / W) + H * math.atan(1 / H) - math.sqrt(S) * math.atan(1 / math.sqrt(S))
    g = (
        (1 + W * W)
        * (1 + H * H)
        / (1 + S)
        * (W * W * (1 + S) / ((1 + W * W) * S)) ** (W * W)
        * (H * H * (1 + S) / ((1 + H * H) * S)) ** (H * H)
    )
    return (t + 0.25 * math.log(g)) / (math.pi * W)


def parallel(a, b, c):
    """Howell C-11: F between directly opposed parallel a x b rectangles at distance c."""
    X, Y = a / c, b / c
    return (
        2
        / (math.pi * X * Y)
        * (
            0.5 * math.log((1 + X * X) * (1 + Y * Y) / (1 + X * X + Y * Y))
            + X * math.sqrt(1 + Y * Y) * math.atan(X / math.sqrt(1 + Y * Y))
            + Y * math.sqrt(1 + X * X) * math.atan(Y / math.sqrt(1 + X * X))
            - X * math.atan(X)
            - Y * math.atan(Y)
        )
    )


def plate(corner, e1, e2, normal, n):
    """A rectangle corner + [0,1] e1 + [0,1] e2 as an n x n grid of quads: vertices, faces, quad centres, normals."""
    corner, e1, e2 = (np.asarray(v, dtype=np.float64) for v in (corner, e1, e2))
    s = np.linspace(0, 1, n + 1)
    S, T = np.meshgrid(s, s, indexing="ij")
    verts = corner + S[..., None] * e1 + T[..., None] * e2
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])
    m = (np.arange(n) + 0.5) / n
    S, T = np.meshgrid(m, m, indexing="ij")
    centres = (corner + S[..., None] * e1 + T[..., None] * e2).reshape(-1, 3)
    normals = np.broadcast_to(np.asarray(normal, dtype=np.float64), centres.shape)
    return verts.reshape(-1, 3), faces, centres, normals


def scene(plates, blockers=()):
    """Tracer, face_patch, origins (Q, K, 3), normals, weights for plates (patches) and blockers (patch -1)."""
    verts, faces, fpatch = [], [], []
    base = 0
    for q, (v, f, *_rest) in enumerate(list(plates) + list(blockers)):
        verts.append(v)
        faces.append(f + base)
        fpatch.append(np.full(len(f), q if q < len(plates) else -1))
        base += len(v)
    origins = np.stack([p[2] for p in plates])
    normals = np.stack([p[3] for p in plates])
    weights = np.ones(origins.shape[:2])
    tracer = RayTracer(np.concatenate(verts), np.concatenate(faces))
    return tracer, np.concatenate(fpatch), origins, normals, weights


def tolerance(f_true, n):
    return 4 * math.sqrt(f_true * (1 - f_true) / n) + DISC


@pytest.mark.parametrize("w,h,l", [(1.0, 1.0, 1.0), (1.0, 2.0, 1.5)])
def test_perpendicular_rectangles_sharing_an_edge(w, h, l):
    if (w, h, l) == (1.0, 1.0, 1.0):
        assert perpendicular(1, 1, 1) == pytest.approx(0.20004, abs=1e-5)
    A = plate((0, 0, 0), (w, 0, 0), (0, l, 0), (0, 0, 1), 100)  # z = 0, normal +z
    B = plate((0, 0, 0), (0, 0, h), (0, l, 0), (1, 0, 0), 100)  # x = 0, normal +x
    N = 100_000
    F = hemisphere_form_factors(*scene([A, B]), samples_per_patch=N, seed=1, offset=OFFSET)
    assert F.shape == (2, 2) and F.dtype == torch.float64
    f_ab, f_ba = perpendicular(w, h, l), perpendicular(h, w, l)
    assert abs(F[0, 1] - f_ab) <= tolerance(f_ab, N)
    assert abs(F[1, 0] - f_ba) <= tolerance(f_ba, N)
    assert F[0, 0] == 0 and F[1, 1] == 0
    # reciprocity A_a F_ab = A_b F_ba, within the combined error bars
    err = math.hypot(w * l * float(sampling_error(F, N)[0, 1]), h * l * float(sampling_error(F, N)[1, 0]))
    assert abs(w * l * F[0, 1] - h * l * F[1, 0]) <= 4 * err + 2 * DISC


@pytest.mark.parametrize("a,b,c", [(1.0, 1.0, 1.0), (1.0, 2.0, 0.7)])
def test_parallel_coaxial_rectangles(a, b, c):
    if (a, b, c) == (1.0, 1.0, 1.0):
        assert parallel(1, 1, 1) == pytest.approx(0.19982, abs=1e-5)
    A = plate((0, 0, 0), (a, 0, 0), (0, b, 0), (0, 0, 1), 60)
    B = plate((0, 0, c), (a, 0, 0), (0, b, 0), (0, 0, -1), 60)
    N = 100_000
    F = hemisphere_form_factors(*scene([A, B]), samples_per_patch=N, seed=2, offset=OFFSET)
    f = parallel(a, b, c)
    assert abs(F[0, 1] - f) <= tolerance(f, N)
    assert abs(F[1, 0] - f) <= tolerance(f, N)


def box(n):
    """The six inward-facing faces of the unit cube as plates."""
    return [
        plate((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), n),
        plate((0, 0, 1), (1, 0, 0), (0, 1, 0), (0, 0, -1), n),
        plate((0, 0, 0), (1, 0, 0), (0, 0, 1), (0, 1, 0), n),
        plate((0, 1, 0), (1, 0, 0), (0, 0, 1), (0, -1, 0), n),
        plate((0, 0, 0), (0, 1, 0), (0, 0, 1), (1, 0, 0), n),
        plate((1, 0, 0), (0, 1, 0), (0, 0, 1), (-1, 0, 0), n),
    ]


def box_truth():
    """(6, 6) analytic F of the unit cube's inner faces: opposite pairs (0,1), (2,3), (4,5)."""
    T = np.full((6, 6), perpendicular(1, 1, 1))
    np.fill_diagonal(T, 0.0)
    for i in (0, 2, 4):
        T[i, i + 1] = T[i + 1, i] = parallel(1, 1, 1)
    return T


def test_closed_box_rows_sum_to_one_and_match_analytic():
    N = 40_000
    F = hemisphere_form_factors(*scene(box(30)), samples_per_patch=N, seed=3, offset=OFFSET)
    assert torch.all(torch.diagonal(F) == 0)  # planar patches do not see themselves
    assert torch.all(F.sum(1) >= 1 - 5.0 / N)  # (almost) no ray escapes a closed box
    assert torch.all(F.sum(1) <= 1 + 1e-12)
    T = box_truth()
    tol = 4 * np.sqrt(T * (1 - T) / N) + DISC
    assert np.all(np.abs(F.numpy() - T) <= tol)


def test_blockers():
    A = plate((-0.5, -0.5, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), 40)
    B = plate((-0.5, -0.5, 1), (1, 0, 0), (0, 1, 0), (0, 0, -1), 40)
    full = plate((-1, -1, 0.5), (2, 0, 0), (0, 2, 0), (0, 0, 1), 4)
    half = plate((-1, -1, 0.5), (1, 0, 0), (0, 2, 0), (0, 0, 1), 4)  # covers x < 0 of the mid-plane
    N = 50_000
    F = hemisphere_form_factors(*scene([A, B], [full]), samples_per_patch=N, seed=4, offset=OFFSET)
    assert F[0, 1] == 0 and F[1, 0] == 0
    # every ray from A to B crosses the mid-plane at the mean of its end points; the reflection
    # x -> -x maps the pairs crossing at x < 0 onto those crossing at x > 0: exactly half is blocked
    F = hemisphere_form_factors(*scene([A, B], [half]), samples_per_patch=N, seed=4, offset=OFFSET)
    f = parallel(1, 1, 1) / 2
    assert abs(F[0, 1] - f) <= tolerance(f, N)
    assert abs(F[1, 0] - f) <= tolerance(f, N)


def test_back_side_of_a_patch_receives_nothing():
    A = plate((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), 30)
    B = plate((0, 0, 1), (1, 0, 0), (0, 1, 0), (0, 0, 1), 30)  # faces away from A
    N = 20_000
    args = scene([A, B])
    F = hemisphere_form_factors(*args, samples_per_patch=N, seed=5, offset=OFFSET)
    assert F[0, 1] == 0 and F[1, 0] == 0
    F = hemisphere_form_factors(*args, samples_per_patch=N, seed=5, offset=OFFSET, count_back_hits=True)
    f = parallel(1, 1, 1)
    assert abs(F[0, 1] - f) <= tolerance(f, N)
    assert F[1, 0] == 0  # B's hemisphere looks away from A


def test_stratified_rays_beat_independent_ones_and_converge_faster_than_one_over_sqrt_n():
    # the rays are randomised QMC (torchrefl.core.rqmc): unbiased like independent rays (the analytic tests
    # above), with an error below the binomial one that independent rays would have, falling faster
    # than 1/sqrt(N) (independent rays: a ratio of 4 for 16x the rays, rms / binomial about 1)
    args = scene(box(30))
    T = box_truth()
    off = ~np.eye(6, dtype=bool)

    def rms(n):
        errs = [
            hemisphere_form_factors(*args, samples_per_patch=n, seed=s, offset=OFFSET).numpy()[off] - T[off]
            for s in range(8)
        ]
        return float(np.sqrt(np.mean(np.square(errs))))

    binomial = lambda n: float(np.sqrt(np.mean(T[off] * (1 - T[off]) / n)))
    coarse, fine = rms(2_000), rms(32_000)
    assert coarse < 0.7 * binomial(2_000)
    assert fine < 0.5 * binomial(32_000)
    assert coarse / fine > 5.0


def test_seed_determinism_and_layouts():
    args = scene(box(8))
    F1 = hemisphere_form_factors(*args, samples_per_patch=3000, seed=7, offset=OFFSET)
    F2 = hemisphere_form_factors(*args, samples_per_patch=3000, seed=7, offset=OFFSET)
    F3 = hemisphere_form_factors(*args, samples_per_patch=3000, seed=8, offset=OFFSET)
    assert torch.equal(F1, F2)
    assert not torch.equal(F1, F3)
    S = hemisphere_form_factors(*args, samples_per_patch=3000, seed=7, offset=OFFSET, layout="sparse")
    assert S.is_sparse and torch.equal(S.to_dense(), F1)
    E = sampling_error(S, 3000)
    assert E.is_sparse and torch.allclose(E.to_dense(), torch.sqrt(F1 * (1 - F1) / 3000))
    # the thread count and the tracer's chunking do not change the result; progress is reported per work unit
    tracer, *rest = args
    for threads in (1, 2, 3):
        other = RayTracer(tracer.vertices, tracer.faces, threads=threads, chunk_size=777)
        calls = []
        F4 = hemisphere_form_factors(
            other,
            *rest,
            samples_per_patch=30_000,
            seed=7,
            offset=OFFSET,
            progress=lambda done, total: calls.append((done, total)),
        )
        if threads == 1:
            F_ref = F4
        assert torch.equal(F4, F_ref)
        assert len(calls) > 1 and calls[-1] == (180_000, 180_000)
        assert all(a[0] < b[0] for a, b in zip(calls, calls[1:]))


def test_padding_and_weights_choose_origins():
    """Zero weights are never sampled: a padded patch gives the same F as the unpadded origins."""
    tracer, fp, o, n, w = scene(box(6))
    N = 20_000
    F = hemisphere_form_factors(tracer, fp, o, n, w, samples_per_patch=N, seed=9, offset=OFFSET)
    # pad every patch with junk origins of weight 0 at the front and back
    junk = np.full((6, 5, 3), 1e3)
    o2 = np.concatenate([junk, o, junk], 1)
    n2 = np.concatenate([np.zeros((6, 5, 3)), n, np.zeros((6, 5, 3))], 1)
    w2 = np.concatenate([np.zeros((6, 5)), w, np.zeros((6, 5))], 1)
    F2 = hemisphere_form_factors(tracer, fp, o2, n2, w2, samples_per_patch=N, seed=9, offset=OFFSET)
    assert torch.all(F2.sum(1) >= 1 - 5.0 / N)
    assert torch.allclose(F2, F, atol=tolerance(0.2, N) * 2)
    # all weight on one origin: the point form factor from the centre of the floor to the ceiling
    # (a unit square at distance 1 seen from the point below its centre: 4 x Howell B-3 corner factor)
    w3 = np.zeros_like(w2)
    o3 = o2.copy()
    o3[0, 0] = (0.5, 0.5, 0.0)
    n3 = n2.copy()
    n3[0, 0] = (0, 0, 1)
    w3[:, 0] = 1.0
    o3[1:, 0], n3[1:, 0] = o[1:, 0], n[1:, 0]
    F3 = hemisphere_form_factors(tracer, fp, o3, n3, w3, samples_per_patch=N, seed=9, offset=OFFSET)
    A = B = 0.5
    corner = (
        A / math.sqrt(1 + A * A) * math.atan(B / math.sqrt(1 + A * A))
        + B / math.sqrt(1 + B * B) * math.atan(A / math.sqrt(1 + B * B))
    ) / (2 * math.pi)
    f = 4 * corner
    assert abs(F3[0, 1] - f) <= 4 * math.sqrt(f * (1 - f) / N)


# --- patches on the texel grid ---------------------------------------------------------------


def small_surface(with_mesh=True):
    H, W = 6, 8
    rng = np.random.default_rng(0)
    r, c = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    pts = np.stack([c * 1.0, r * 1.0, 0.1 * np.sin(c) * np.cos(r)], -1)
    valid = np.ones((H, W), dtype=bool)
    valid[0, 0] = valid[2, 5] = valid[5, 7] = valid[3, 3] = False
    normals = rng.normal(size=(H, W, 3)) * 0.2 + (0, 0, 1)
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    areas = rng.uniform(0.5, 2.0, size=(H, W))
    idx = np.flatnonzero(valid.ravel())
    verts, faces = grid_triangulation(pts, valid) if with_mesh else (None, None)
    surf = Surface(
        grid_shape=(H, W),
        texel_index=torch.as_tensor(idx),
        positions=torch.as_tensor(pts.reshape(-1, 3)[idx]),
        normals=torch.as_tensor(normals.reshape(-1, 3)[idx]),
        areas=torch.as_tensor(areas.ravel()[idx]),
        mesh_vertices=verts,
        mesh_faces=faces,
    )
    return surf, pts, normals, areas, valid


@pytest.mark.parametrize("s", [1, 3, 4])
def test_texel_patches_membership_areas_normals(s):
    surf, pts, normals, areas, valid = small_surface()
    P = texel_patches(surf, s)
    H, W = valid.shape
    # slow reference: loop over blocks in row-major block order
    texel_of = {int(f): t for t, f in enumerate(surf.texel_index.tolist())}
    q = 0
    for bi in range(-(-H // s)):
        for bj in range(-(-W // s)):
            cells = [
                (r, c)
                for r in range(bi * s, min(H, bi * s + s))
                for c in range(bj * s, min(W, bj * s + s))
                if valid[r, c]
            ]
            if not cells:
                continue
            members = sorted(texel_of[r * W + c] for r, c in cells)
            assert P.members(q).tolist() == members
            assert all(int(P.texel_patch[t]) == q for t in members)
            a = np.array([areas[r, c] for r, c in cells])
            assert float(P.areas[q]) == pytest.approx(a.sum())
            x = np.array([pts[r, c] for r, c in cells])
            assert P.centres[q].numpy() == pytest.approx((a[:, None] * x).sum(0) / a.sum())
            nm = (a[:, None] * np.array([normals[r, c] for r, c in cells])).sum(0)
            assert P.normals[q].numpy() == pytest.approx(nm / np.linalg.norm(nm))
            assert P.block[q].tolist() == [bi, bj]
            q += 1
    assert P.num_patches == q
    if s == 1:
        assert torch.equal(P.texel_patch, torch.arange(surf.num_texels))
    pos, mask = P.padded(surf.positions)
    assert int(mask.sum()) == surf.num_texels
    assert torch.equal(pos[mask].sum(0), surf.positions[P.member_texels].sum(0))


def split_reference(surf, s, angle_deg):
    """Slow, obvious split of every block: repeatedly take the block's lowest-index unplaced texel and put
    every unplaced texel within angle_deg of its normal in its patch. Returns the patches as sorted
    member lists in block order, then split order."""
    H, W = surf.grid_shape
    n = surf.normals.numpy()
    cos_min = math.cos(math.radians(angle_deg))
    by_block = {}
    for t, f in enumerate(surf.texel_index.tolist()):
        by_block.setdefault(((f // W) // s, (f % W) // s), []).append(t)
    out = []
    for key in sorted(by_block):
        left = sorted(by_block[key])
        while left:
            seed = left[0]
            part = [t for t in left if t == seed or float(n[t] @ n[seed]) >= cos_min]
            out.append((key, part))
            left = [t for t in left if t not in part]
    return out


@pytest.mark.parametrize("s,angle", [(2, 20.0), (3, 15.0), (4, 25.0), (3, 180.0)])
def test_blocks_split_where_normals_disagree_like_the_slow_reference(s, angle):
    surf, *_ = small_surface()  # normals tilted at random by ~0.2 rad: some blocks split, most do not
    P = texel_patches(surf, s, split_angle_deg=angle)
    ref = split_reference(surf, s, angle)
    assert P.num_patches == len(ref)
    for q, (block, members) in enumerate(ref):
        assert P.members(q).tolist() == members
        assert P.block[q].tolist() == list(block)
    blocks = len({b for b, _ in ref})
    if angle < 180:
        assert P.num_patches > blocks  # the case splits something
    else:
        assert P.num_patches == blocks


def test_a_patch_does_not_straddle_a_fold():
    """Fold grid with 5 columns per plate: the 2-texel blocks of columns 4-5 straddle the fold line. Split at
    30 degrees, they become one patch per plate (same block), with that plate's normal; unsplit, one patch
    holds both plates with a 45-degree mean normal."""
    from conftest import fold_surface

    surf = fold_surface(6, 10)
    n = surf.normals
    plain = texel_patches(surf, 2)
    split = texel_patches(surf, 2, split_angle_deg=30.0)
    assert plain.num_patches == 15 and split.num_patches == 18
    spread = lambda P, q: float((n[P.members(q)] * n[P.members(q)[0]]).sum(-1).min())  # smallest cosine to the first
    assert sum(spread(plain, q) < 0.5 for q in range(plain.num_patches)) == 3
    for q in range(split.num_patches):
        assert spread(split, q) > 0.999
        torch.testing.assert_close(split.normals[q], n[split.members(q)[0]])
    assert torch.unique(split.block, dim=0).shape[0] == 15


def test_face_patches_follow_the_first_vertex():
    surf, _, _, _, valid = small_surface()
    H, W = valid.shape
    s = 3
    P = texel_patches(surf, s)
    fp = face_patches(surf, P)
    assert fp.shape == (len(surf.mesh_faces),)
    blocks = {tuple(b): q for q, b in enumerate(P.block.tolist())}
    for f, q in zip(surf.mesh_faces, fp):
        r, c = divmod(int(f[0]), W)
        assert valid[r, c]  # grid_triangulation only makes quads of valid corners
        assert q == blocks[(r // s, c // s)]
    # a face whose first vertex is not a valid texel belongs to no patch
    faces = surf.mesh_faces.copy()
    faces[0, 0] = 0  # texel (0, 0) is invalid
    surf2 = Surface(
        grid_shape=surf.grid_shape,
        texel_index=surf.texel_index,
        positions=surf.positions,
        normals=surf.normals,
        areas=surf.areas,
        mesh_vertices=surf.mesh_vertices,
        mesh_faces=faces,
    )
    assert face_patches(surf2, P)[0] == -1


def fold_surface(n=16, h=1.0 / 16):
    """Two perpendicular n x n-texel plates meeting at a fold, as a range-image grid (n rows, 2n columns):
    plate 1 in z = 0 (normal +z), plate 2 in x = X (normal -x), texel centres at the cell centres."""
    H, W = n, 2 * n
    r, c = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    y = (r + 0.5) * h
    X = n * h
    first = c < n
    x = np.where(first, (c + 0.5) * h, X)
    z = np.where(first, 0.0, (c - n + 0.5) * h)
    pts = np.stack([x, y, z], -1)
    nrm = np.where(first[..., None], (0.0, 0.0, 1.0), (-1.0, 0.0, 0.0))
    valid = np.ones((H, W), dtype=bool)
    # the triangulated mesh: the exact plates (not the texel-centre grid), as a vertex grid of H x W
    # points so that face_patches' layout holds; vertices are the texel cell corners shifted by half a cell
    verts, faces = grid_triangulation(pts, valid)
    return Surface(
        grid_shape=(H, W),
        texel_index=torch.arange(H * W),
        positions=torch.as_tensor(pts.reshape(-1, 3)),
        normals=torch.as_tensor(nrm.reshape(-1, 3)),
        areas=torch.full((H * W,), h * h),
        mesh_vertices=verts,
        mesh_faces=faces,
    ), first.ravel()


def test_form_factors_for_surface_fold_reciprocity():
    surf, first = fold_surface()
    N = 2000
    P, F = form_factors_for_surface(surf, None, patch_size=4, samples_per_patch=N, seed=0, offset=1e-5)
    Q = P.num_patches
    assert F.shape == (Q, Q) and Q == 4 * 8
    Fd = F.to_dense().numpy()
    A = P.areas.numpy()
    # rows are fractions of emitted energy
    assert np.all(Fd.sum(1) <= 1 + 1e-12)
    # plate-to-plate aggregate: reciprocity of the sums, and the analytic value for the two plates
    # within a loose bound (the mesh through the texel centres is trimmed by half a texel on every
    # side and chamfered at the fold: measured 0.189 against 0.200)
    on1 = np.zeros(Q, dtype=bool)
    on1[np.unique(P.texel_patch.numpy()[first])] = True
    flow12 = (A[on1, None] * Fd[np.ix_(on1, ~on1)]).sum()
    flow21 = (A[~on1, None] * Fd[np.ix_(~on1, on1)]).sum()
    total = A[on1].sum()
    assert flow12 / total == pytest.approx(flow21 / total, abs=0.01)
    assert flow12 / total == pytest.approx(perpendicular(1, 1, 1), abs=0.03)
    # coplanar patches do not see each other, and the mesh's chamfer across the fold (the quads between the
    # last texel column of plate 1 and the first of plate 2) counts as the other plate (the corner rule)
    assert np.all(Fd[np.ix_(on1, on1)] == 0) and np.all(Fd[np.ix_(~on1, ~on1)] == 0)


def test_the_strip_that_cuts_the_fold_is_seen_as_the_other_plate():
    """The range mesh joins the last texel column of one plate to the first of the other with a strip of faces
    that cuts the fold's corner, each face owned by a texel of one side. A ray from that side's texels that lands
    on the strip would, on the real object, reach the other plate: with the corner rule (face_corners) no texel
    sees its own plate, and the plate-to-plate flow comes closer to Howell's C-14 than when each face counts as
    its owner's (corners=None: the owner's row sees itself)."""
    from torchrefl.transport.patches import face_corners

    surf, first = fold_surface()
    N = 2000
    P, F = form_factors_for_surface(surf, None, patch_size=1, samples_per_patch=N, seed=0, offset=1e-5)
    pos, nrm, area, mask = P.padded(surf.positions.double(), surf.normals.double(), surf.areas.double())
    tracer = RayTracer(surf.mesh_vertices, surf.mesh_faces)
    plain = hemisphere_form_factors(
        tracer, face_patches(surf, P), pos, nrm, area * mask, samples_per_patch=N, seed=0, offset=1e-5
    )
    again = hemisphere_form_factors(
        tracer,
        face_patches(surf, P),
        pos,
        nrm,
        area * mask,
        samples_per_patch=N,
        seed=0,
        offset=1e-5,
        corners=face_corners(surf, P),
    )
    torch.testing.assert_close(again.to_dense(), F.to_dense())
    on1 = np.zeros(P.num_patches, dtype=bool)
    on1[P.texel_patch.numpy()[first]] = True
    A = P.areas.numpy()
    out = {}
    for name, M in (("corners", F.to_dense().numpy()), ("plain", plain.to_dense().numpy())):
        same = (A[on1, None] * M[np.ix_(on1, on1)]).sum() + (A[~on1, None] * M[np.ix_(~on1, ~on1)]).sum()
        out[name] = (same / A.sum(), (A[on1, None] * M[np.ix_(on1, ~on1)]).sum() / A[on1].sum())
    assert out["corners"][0] == 0.0 and out["plain"][0] > 0.005, out
    exact = perpendicular(1, 1, 1)
    assert abs(out["corners"][1] - exact) < abs(out["plain"][1] - exact), (out, exact)


# --- bad inputs --------------------------------------------------------------------------------


def test_bad_inputs_raise_named_errors():
    tracer, fp, o, n, w = scene(box(3))
    ok = dict(samples_per_patch=10, seed=0, offset=OFFSET)
    with pytest.raises(GeometryError, match=r"corners have shapes \(1, 3\) and \(1, 3, 3\), expected"):
        hemisphere_form_factors(tracer, fp, o, n, w, corners=(np.zeros((1, 3)), np.zeros((1, 3, 3))), **ok)
    with pytest.raises(ConfigError, match="samples_per_patch"):
        hemisphere_form_factors(tracer, fp, o, n, w, samples_per_patch=0, seed=0, offset=OFFSET)
    with pytest.raises(ConfigError, match="offset"):
        hemisphere_form_factors(tracer, fp, o, n, w, samples_per_patch=10, seed=0, offset=-1.0)
    with pytest.raises(ConfigError, match="layout"):
        hemisphere_form_factors(tracer, fp, o, n, w, layout="csc", **ok)
    with pytest.raises(GeometryError, match="origins"):
        hemisphere_form_factors(tracer, fp, o[..., :2], n, w, **ok)
    with pytest.raises(GeometryError, match="normals"):
        hemisphere_form_factors(tracer, fp, o, n[:, :4], w, **ok)
    with pytest.raises(GeometryError, match="normals"):
        hemisphere_form_factors(tracer, fp, o, 2 * n, w, **ok)
    with pytest.raises(GeometryError, match="weights"):
        hemisphere_form_factors(tracer, fp, o, n, w[:, :4], **ok)
    with pytest.raises(GeometryError, match="weights"):
        hemisphere_form_factors(tracer, fp, o, n, -w, **ok)
    w0 = w.copy()
    w0[2] = 0
    with pytest.raises(GeometryError, match="weights of patch 2"):
        hemisphere_form_factors(tracer, fp, o, n, w0, **ok)
    with pytest.raises(GeometryError, match="face_patch"):
        hemisphere_form_factors(tracer, fp[:-1], o, n, w, **ok)
    bad = fp.copy()
    bad[0] = 6
    with pytest.raises(GeometryError, match="face_patch"):
        hemisphere_form_factors(tracer, bad, o, n, w, **ok)
    surf, *_ = small_surface()
    with pytest.raises(ConfigError, match="patch_size"):
        texel_patches(surf, 0)
    with pytest.raises(ConfigError, match="split_angle_deg"):
        texel_patches(surf, 2, split_angle_deg=200.0)
    with pytest.raises(ConfigError, match="patch_size"):
        form_factors_for_surface(surf, None, patch_size=1.5, samples_per_patch=10, seed=0, offset=1e-4)
    with pytest.raises(ConfigError, match="samples_per_patch"):
        form_factors_for_surface(surf, None, patch_size=2, samples_per_patch=0, seed=0, offset=1e-4)
    no_mesh, *_ = small_surface(with_mesh=False)
    with pytest.raises(GeometryError, match="mesh"):
        form_factors_for_surface(no_mesh, None, patch_size=2, samples_per_patch=10, seed=0, offset=1e-4)
    with pytest.raises(GeometryError, match="mesh"):
        face_patches(no_mesh, texel_patches(no_mesh, 2))
    short = Surface(
        grid_shape=surf.grid_shape,
        texel_index=surf.texel_index,
        positions=surf.positions,
        normals=surf.normals,
        areas=surf.areas,
        mesh_vertices=surf.mesh_vertices[:-1],
        mesh_faces=np.zeros((1, 3), dtype=np.int64),
    )
    with pytest.raises(GeometryError, match="mesh_vertices"):
        face_patches(short, texel_patches(short, 2))


def test_form_factors_inside_a_closed_atlas_mesh_sum_to_one():
    """The inside of a closed cube on its atlas (every wall a chart, its UVs off the texel grid): every hemisphere
    ray from a patch lands on the front of some patch, so each row of F sums to 1 (the texel-grid mesh that stood in
    for the real one lost 16 % through its seams: docs/results/mesh_views.md)."""
    from conftest import atlas_room

    s = atlas_room().surface
    for size in (1, 4):
        _, F = form_factors_for_surface(s, patch_size=size, samples_per_patch=128, seed=0)
        rows = F.to_dense().sum(1)
        assert torch.allclose(rows, torch.ones_like(rows))
        assert float(F.to_dense().diagonal().max()) == 0.0  # a flat wall does not see itself
