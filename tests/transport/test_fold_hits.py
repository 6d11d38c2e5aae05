"""The corner rule for hits on faces that bridge a fold, against a slow per-hit reference."""

import numpy as np

from torchrefl.transport.fold_hits import MIXED_COS, facing_corner, mixed_faces


def reference(corner, normals, d, score, usable):
    out = []
    for c, n, di, sc, us in zip(corner, normals, d, score, usable):
        faces = [k for k in range(3) if us[k] and float(n[k] @ di) < 0]
        if (us[c] and float(n[c] @ di) < 0) or not faces:
            out.append(c)
        else:
            out.append(max(faces, key=lambda k: sc[k]))
    return np.array(out)


def test_facing_corner_matches_the_slow_reference():
    rng = np.random.default_rng(7)
    n = rng.normal(size=(500, 3, 3))
    n /= np.linalg.norm(n, axis=2, keepdims=True)
    d = rng.normal(size=(500, 3))
    corner = rng.integers(0, 3, 500)
    score = rng.random((500, 3))
    usable = rng.random((500, 3)) > 0.2
    np.testing.assert_array_equal(facing_corner(corner, n, d, score, usable), reference(corner, n, d, score, usable))
    np.testing.assert_array_equal(
        facing_corner(corner, n, d, score), reference(corner, n, d, score, np.ones((500, 3), bool))
    )


def test_a_fold_strip_face_is_mixed_and_a_flat_or_gently_bent_one_is_not():
    up, wall = np.array([0.0, 0.0, 1.0]), np.array([-1.0, 0.0, 0.0])
    tilt = np.array([np.sin(0.3), 0.0, np.cos(0.3)])  # 17 degrees off: cos 0.955 > MIXED_COS
    faces = np.stack([np.stack([up, up, wall]), np.stack([up, up, up]), np.stack([up, tilt, up])])
    np.testing.assert_array_equal(mixed_faces(faces), [True, False, False])
    assert float(up @ tilt) > MIXED_COS
