import hashlib

import numpy as np
import pytest

from cuboidlib import shapes
from cuboidlib.shapes import CATEGORIES, PART_NAMES, STRUCTURES, ShapeCollection, make_collection, make_shape
from cuboidlib.solids import Cylinder, union_sdf

N_SHAPES = 6  # per category, for the per-point geometric checks

#: The generator's shapes 0, 1, 2, 7 and 42 of seed 0, hashed by :func:`fingerprint`: the parts of ``build_parts``
#: (rounded to 1e-6) and 256 points of ``make_shape`` (points rounded to 1e-5, normals to 1e-4, labels and
#: instances exact). Computed before the generator was split by category and versioned, by
#: ``python -c "from tests.test_shapes import fingerprint; print(fingerprint('chair', version=1))"`` (and so on per
#: category) from the repository root (``version=1`` left out then); version 1 must keep them for ever.
VERSION_1_FINGERPRINTS = {
    "chair": "05e39f99213c60a2fbc10b37e4eda7a170562f598f66e9fc275c10efe91e9a50",
    "table": "411f6b0be70f1fc9ce638e4fe9447725a0c54cd76f920ef5157fc9a77a253bde",
    "airplane": "b5650c7613277b0fff71e03e70e656321352151146d735fc312e9fc90b7030d9",
    "animal": "fc8710603f3d923b831d2095303d2c6b618b9cd127fb422508ed0bbd35658f9f",
}
FINGERPRINT_INDICES = (0, 1, 2, 7, 42)


def _digest(h, a, decimals=None) -> None:
    a = np.asarray(a)
    if decimals is not None:  # rounded, so that another CPU's last bits do not change the hash
        a = np.round(a.astype(np.float64), decimals) + 0.0  # + 0.0: -0.0 and 0.0 hash alike
    h.update(np.ascontiguousarray(a).tobytes())


def fingerprint(category: str, **version) -> str:
    """sha256 of the parts and of 256 sampled points of shapes FINGERPRINT_INDICES (seed 0) of ``category``."""
    h = hashlib.sha256()
    for i in FINGERPRINT_INDICES:
        solids, structure, sid = shapes.build_parts(category, i, 0, **version)
        h.update(f"{structure}|{sid}".encode())
        for p in solids:
            h.update(f"{type(p).__name__}|{p.label}".encode())
            for k, v in sorted(vars(p).items()):
                if not k.startswith("_") and k != "label":
                    _digest(h, np.asarray(v, np.float64), 6)
        s = make_shape(category, i, 256, 0, **version)
        for a, decimals in ((s.points, 5), (s.normals, 4), (s.labels, None), (s.instances, None)):
            _digest(h, a, decimals)
    return h.hexdigest()


@pytest.fixture(scope="module")
def samples():
    return {c: [make_shape(c, i, n_points=1024, seed=3) for i in range(N_SHAPES)] for c in CATEGORIES}


def _own_part(shape, i_point):
    """Index of the part of the point's label whose surface it lies on."""
    p = shape.points[i_point].astype(np.float64)[None]
    cands = [j for j, s in enumerate(shape.parts) if s.label == shape.labels[i_point]]
    return min(cands, key=lambda j: abs(shape.parts[j].sdf(p)[0]))


@pytest.mark.parametrize("category", CATEGORIES)
def test_version_1_shapes_keep_their_fingerprint_and_later_versions_change_only_airplanes_and_animals(category):
    assert fingerprint(category, version=1) == VERSION_1_FINGERPRINTS[category]
    assert (fingerprint(category, version=2) == VERSION_1_FINGERPRINTS[category]) == (category in ("chair", "table"))
    assert (fingerprint(category, version=3) == fingerprint(category, version=2)) == (category != "animal")
    assert shapes.GENERATOR_VERSION == 3 and fingerprint(category) == fingerprint(category, version=3)


def test_version_3_animals_are_version_2_without_the_thighs():
    for i in range(20):
        two, st2, sid2 = shapes.build_parts("animal", i, 0, version=2)
        three, st3, sid3 = shapes.build_parts("animal", i, 0, version=3)
        legs2, legs3 = [s for s in two if s.label == 2], [s for s in three if s.label == 2]
        assert (len(legs2), len(legs3)) == (12, 8), "version 2: four thighs beside the eight leg capsules"
        assert (st2, sid2) == (st3, sid3) and len(two) - len(three) == 4


def test_a_bad_generator_version_is_refused_with_the_versions_named():
    for bad in (0, 4, True, 2.0, "2", None):
        for call in (lambda: make_shape("chair", 0, 64, version=bad), lambda: shapes.build_parts("animal", 0, version=bad),
                     lambda: make_collection("airplane", 2, 64, use_cache=False, version=bad)):
            with pytest.raises(ValueError, match=r"generator version must be one of \(1, 2, 3\)"):
                call()


N_DRAWS = 200  # version-2 shapes per category for the rates of the new variants


def _rate_ok(count: int, n: int, rate: float) -> bool:
    """``count`` of ``n`` draws is within 4 binomial standard deviations of ``rate``."""
    return abs(count - n * rate) <= 4 * (n * rate * (1 - rate)) ** 0.5


def test_version_2_airplanes_draw_light_aircraft_and_landing_gear_at_their_rates():
    from cuboidlib.shapes_airplane import GEAR_SHARE, LIGHT_AIRCRAFT_SHARE

    drawn = [shapes.build_parts("airplane", i, 0, version=2) for i in range(N_DRAWS)]
    light = [(solids, st) for solids, st, sid in drawn if STRUCTURES["airplane"][sid] == "propeller"]
    others = [st for solids, st, sid in drawn if STRUCTURES["airplane"][sid] != "propeller"]
    assert _rate_ok(len(light), N_DRAWS, LIGHT_AIRCRAFT_SHARE)
    assert _rate_ok(sum("+gear" in st for st in others), len(others), GEAR_SHARE)
    for solids, st, _ in drawn:  # a gear's wheels: discs across x (axis along x), labelled body
        wheels = [s for s in solids if isinstance(s, Cylinder) and s.label == 0 and abs(s.R[0, 2]) > 0.99]
        assert len(wheels) == (3 if "+gear" in st else 0)
    assert sum("+gear" in st for _, st in light) > 0.6 * len(light)
    for i in [i for i, (_, _, sid) in enumerate(drawn) if STRUCTURES["airplane"][sid] == "propeller"][:8]:
        s = make_shape("airplane", i, 1024, 0, version=2)
        engine, body = s.points[s.labels == 3], s.points[s.labels == 0]
        assert len(engine) and engine[:, 2].min() > np.percentile(body[:, 2], 90), "the only engine is on the nose"


def _tail_angle(solids) -> float:
    tail = [s for s in solids if s.label == 3]
    v = tail[-1].b - tail[0].a
    return float(np.degrees(np.arctan2(v[1], -v[2])))


def test_version_2_animals_draw_posed_tails_wider_bodies_and_thighs_at_their_rates():
    from cuboidlib.shapes_animal import TAIL_POSES, WIDE_SHARE

    drawn = [shapes.build_parts("animal", i, 0, version=2) for i in range(N_DRAWS)]
    structures = [st for _, st, _ in drawn]
    for pose, weight, (lo, hi) in TAIL_POSES:
        posed = [solids for solids, st, _ in drawn if f"+{pose}-tail" in st]
        assert _rate_ok(len(posed), N_DRAWS, weight)
        angles = [_tail_angle(solids) for solids in posed]  # between 0.75 and 1.2 times the drawn angle
        assert max(min(1.2 * lo, 0.75 * lo), -88) - 1e-6 <= min(angles) and max(angles) <= max(1.2 * hi, 0.75 * hi)
    angles = [_tail_angle(solids) for solids, _, _ in drawn]
    assert min(angles) < -75 and max(angles) > 65, "tails from hanging to raised"
    assert _rate_ok(sum("+wide" in st for st in structures), N_DRAWS, WIDE_SHARE)
    ends = [[s for s in solids if s.label == 3] for solids, _, _ in drawn]
    length = np.array([np.linalg.norm(tail[-1].b - tail[0].a) for tail in ends])  # body length 1 before scaling
    v1_short = [np.linalg.norm(tail[-1].b - tail[0].a) < 0.16 for tail in
                ([s for s in shapes.build_parts("animal", i, 0, version=1)[0] if s.label == 3] for i in range(N_DRAWS))]
    assert length.max() <= 0.7 + 1e-9 and np.mean(length < 0.16) < 0.1 < np.mean(v1_short), "no stubs of tails"


def test_version_2_leg_labels_reach_up_the_body_as_on_the_real_meshes_and_version_3_as_version_1():
    for i in range(12):
        for version, lo, hi in ((1, 0.2, 0.42), (2, 0.42, 0.8), (3, 0.2, 0.42)):
            s = make_shape("animal", i, 2048, 0, version=version)
            body_y, leg_y = s.points[s.labels == 0, 1], s.points[s.labels == 2, 1]
            up = (np.percentile(leg_y, 99) - body_y.min()) / np.ptp(body_y)  # transfer_causes' statistic
            assert lo < up < hi, (version, i, up)


def test_collections_of_two_versions_are_cached_apart(tmp_path):
    one = make_collection("animal", 2, 64, seed=0, cache_dir=tmp_path, version=1)
    two = make_collection("animal", 2, 64, seed=0, cache_dir=tmp_path, version=2)
    assert sorted(p.name for p in tmp_path.glob("*.npz")) == ["animal_S2_N64_seed0_v1.npz", "animal_S2_N64_seed0_v2.npz"]
    assert (one.generator_version, two.generator_version) == (1, 2) and not np.array_equal(one.points, two.points)
    again = ShapeCollection.load(tmp_path / "animal_S2_N64_seed0_v1.npz")
    assert again.generator_version == 1
    np.testing.assert_array_equal(again.points, one.points)


def test_part_names_and_structures_follow_the_paper_categories():
    assert PART_NAMES["chair"] == ("back", "seat", "leg", "arm")
    assert PART_NAMES["table"] == ("top", "leg")
    assert PART_NAMES["airplane"] == ("body", "wing", "tail", "engine")
    assert PART_NAMES["animal"] == ("body", "head", "leg", "tail")
    assert set(STRUCTURES) == set(CATEGORIES)


@pytest.mark.parametrize("category", CATEGORIES)
def test_every_point_has_a_label_a_unit_normal_and_the_shape_is_normalised(samples, category):
    for s in samples[category]:
        assert s.points.shape == (1024, 3) and s.points.dtype == np.float32
        assert s.normals.shape == (1024, 3) and s.normals.dtype == np.float32
        assert s.labels.shape == (1024,) and s.labels.dtype == np.int64
        assert s.labels.min() >= 0 and s.labels.max() < len(PART_NAMES[category])
        np.testing.assert_allclose(np.linalg.norm(s.normals, axis=1), 1.0, atol=1e-5)
        lo, hi = s.points.min(0), s.points.max(0)
        np.testing.assert_allclose((lo + hi) / 2, 0.0, atol=1e-6)
        assert np.linalg.norm(hi - lo) == pytest.approx(1.0, abs=1e-5)


@pytest.mark.parametrize("category", CATEGORIES)
def test_points_are_on_the_outer_surface_with_outward_normals(samples, category):
    eps = 1e-4
    for s in samples[category]:
        p, n = s.points.astype(np.float64), s.normals.astype(np.float64)
        d = union_sdf(s.parts, p)
        # on the union's boundary: not buried inside any other part
        assert np.abs(d).max() < 1e-5, "a point lies inside the union, not on its outer surface"
        # outward with respect to the part the point was sampled on
        for i in range(0, len(p), 7):
            part = s.parts[_own_part(s, i)]
            assert part.sdf(p[i:i + 1] + eps * n[i:i + 1])[0] > 0 and part.sdf(p[i:i + 1] - eps * n[i:i + 1])[0] < 0
        # ... and with respect to the whole shape: stepping along the normal leaves the union
        # (a point at a concave junction can step into a neighbouring part, hence the 1 % margin)
        assert (union_sdf(s.parts, p + eps * n) > 0).mean() > 0.99


@pytest.mark.parametrize("category", CATEGORIES)
def test_no_points_on_faces_where_two_parts_touch(samples, category):
    # A point on part A that also lies on the surface of part B, with B's outward normal opposite
    # to A's, sits on an internal contact face (buried between the parts).
    h = 1e-6
    for s in samples[category]:
        p, n = s.points.astype(np.float64), s.normals.astype(np.float64)
        for part in s.parts:
            near = np.abs(part.sdf(p)) < 1e-5
            if not near.any():
                continue
            q = p[near]
            grad = np.stack([(part.sdf(q + h * e) - part.sdf(q - h * e)) / (2 * h) for e in np.eye(3)], axis=1)
            grad /= np.linalg.norm(grad, axis=1, keepdims=True)
            assert ((grad * n[near]).sum(axis=1) > -0.99).all()


@pytest.mark.parametrize("category", CATEGORIES)
def test_structure_strings_match_the_parts_present(category):
    coll = make_collection(category, 40, n_points=512, seed=1, use_cache=False)
    assert len(set(coll.structure_ids.tolist())) >= 3, "several coarse structures in a small collection"
    for st, sid, lab in zip(coll.structures, coll.structure_ids, coll.labels):
        coarse = STRUCTURES[category][sid]
        present = {PART_NAMES[category][k] for k in np.unique(lab)}
        if category == "chair":
            assert st.startswith(coarse.split("+")[0])
            assert ("+arms" in st) == ("arm" in present) == coarse.endswith("+arms")
            assert {"back", "seat", "leg"} <= present
        elif category == "table":
            assert present == {"top", "leg"} and st.startswith(coarse)
        elif category == "airplane":
            assert ("engine" in present) == (not coarse.startswith("engines0"))
            assert ("+t-tail" in st) == coarse.endswith("+t-tail") or coarse == "propeller"  # light aircraft: either
            assert st.startswith("propeller") == (coarse == "propeller")
            assert {"body", "wing", "tail"} <= present
        else:
            assert present == set(PART_NAMES["animal"]) and st.split("+")[0] == coarse


def test_shapes_are_upright_and_face_plus_z(samples):
    for s in samples["chair"]:
        mean = {k: s.points[s.labels == i].mean(0) for i, k in enumerate(PART_NAMES["chair"]) if (s.labels == i).any()}
        assert mean["back"][1] > mean["seat"][1] > mean["leg"][1]
        assert mean["back"][2] < mean["seat"][2], "the back is behind the seat (fronts face +z)"
    for s in samples["table"]:
        assert s.points[s.labels == 0, 1].min() > s.points[s.labels == 1, 1].mean()
    for s in samples["airplane"]:
        nose = 3 if s.structure.startswith("propeller") else 0
        assert s.labels[np.argmax(s.points[:, 2])] == nose, "the nose (body, or a propeller) is the front-most point"
        assert s.points[s.labels == 2, 2].mean() < s.points[s.labels == 1, 2].mean(), "tail behind the wings"
        assert np.ptp(s.points[s.labels == 1, 0]) > np.ptp(s.points[s.labels == 1, 2]), "wings span x"
    for s in samples["animal"]:
        assert s.points[s.labels == 1, 2].mean() > s.points[s.labels == 0, 2].mean() > s.points[s.labels == 3, 2].mean()
        assert s.labels[np.argmin(s.points[:, 1])] == 2, "the lowest point is a foot"


def test_generation_is_deterministic_and_prefix_stable(tmp_path):
    a = make_shape("chair", 5, n_points=256, seed=2)
    b = make_shape("chair", 5, n_points=256, seed=2)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.labels, b.labels)
    c = make_shape("chair", 5, n_points=256, seed=3)
    assert not np.array_equal(a.points, c.points)
    small = make_collection("animal", 3, 128, seed=4, use_cache=False)
    big = make_collection("animal", 5, 128, seed=4, use_cache=False)
    np.testing.assert_array_equal(small.points, big.points[:3])
    np.testing.assert_array_equal(small.structures, big.structures[:3])
    one = make_shape("animal", 2, 128, seed=4)
    np.testing.assert_array_equal(one.points, big.points[2])
    assert one.structure == big.structures[2] and one.structure_id == big.structure_ids[2]


def test_collection_save_load_round_trip_without_pickle(tmp_path):
    coll = make_collection("table", 4, 64, seed=0, use_cache=False)
    path = coll.save(tmp_path / "t.npz")
    with np.load(path, allow_pickle=False) as z:
        assert z["points"].shape == (4, 64, 3)
    back = ShapeCollection.load(path)
    assert back.category == "table" and back.seed == 0 and len(back) == 4
    for name in ("points", "normals", "labels", "structures", "structure_ids", "instances"):
        np.testing.assert_array_equal(getattr(back, name), getattr(coll, name))


@pytest.mark.parametrize("category", CATEGORIES)
def test_each_point_knows_the_solid_it_was_sampled_on(samples, category):
    for s in samples[category]:
        assert s.instances.shape == s.labels.shape and s.instances.dtype == np.int64
        np.testing.assert_array_equal(s.labels, np.array([p.label for p in s.parts])[s.instances])
        sdf = np.stack([p.sdf(s.points.astype(np.float64)) for p in s.parts])  # (parts, N)
        own = np.abs(sdf[s.instances, np.arange(len(s.points))])
        assert np.median(own) < 1e-4  # each point lies on the surface of its own solid
    coll = make_collection(category, N_SHAPES, 1024, seed=3, use_cache=False)
    np.testing.assert_array_equal(coll.instances, np.stack([s.instances for s in samples[category]]))


def test_a_cache_file_without_instances_is_regenerated_and_an_old_file_still_loads(tmp_path):
    coll = make_collection("chair", 2, 32, seed=0, cache_dir=tmp_path)
    (path,) = tmp_path.glob("*.npz")
    with np.load(path) as z:
        old = {k: z[k] for k in z.files if k != "instances"}
    np.savez(path, **old)
    assert ShapeCollection.load(path).instances is None
    again = make_collection("chair", 2, 32, seed=0, cache_dir=tmp_path)
    np.testing.assert_array_equal(again.instances, coll.instances)
    np.savez(path, **old, instances=-np.ones((2, 32), np.int64))
    with pytest.raises(ValueError, match="instances must be non-negative integers"):
        ShapeCollection.load(path)


def test_collections_are_cached_by_their_arguments(tmp_path, monkeypatch):
    coll = make_collection("airplane", 3, 64, seed=5, cache_dir=tmp_path)
    files = list(tmp_path.glob("*.npz"))
    assert len(files) == 1 and "airplane" in files[0].name and "seed5" in files[0].name

    def fail(*args, **kwargs):
        raise AssertionError("a cached collection must not be regenerated")

    monkeypatch.setattr(shapes, "_sample_shape", fail)
    again = make_collection("airplane", 3, 64, seed=5, cache_dir=tmp_path)
    np.testing.assert_array_equal(again.points, coll.points)
    with pytest.raises(AssertionError, match="regenerated"):
        make_collection("airplane", 3, 64, seed=6, cache_dir=tmp_path)  # another key
    monkeypatch.setenv("CUBOIDLIB_CACHE", str(tmp_path / "env"))
    assert shapes.default_cache_dir() == tmp_path / "env"


def test_a_corrupt_cache_file_is_regenerated(tmp_path):
    coll = make_collection("chair", 2, 32, seed=0, cache_dir=tmp_path)
    (path,) = tmp_path.glob("*.npz")
    path.write_bytes(b"not an npz file")
    again = make_collection("chair", 2, 32, seed=0, cache_dir=tmp_path)
    np.testing.assert_array_equal(again.points, coll.points)


def test_mesh_of_a_shape_matches_its_points(samples):
    s = samples["chair"][0]
    mesh = s.mesh()
    assert len(mesh.faces) == len(mesh.face_attributes["label"])
    assert set(np.unique(mesh.face_attributes["label"])) == set(np.unique(s.labels))
    np.testing.assert_allclose(mesh.bounds[0], s.points.min(0), atol=0.02)
    np.testing.assert_allclose(mesh.bounds[1], s.points.max(0), atol=0.02)


def test_bad_arguments():
    with pytest.raises(ValueError, match="category must be one of"):
        make_shape("sofa")
    with pytest.raises(ValueError, match="n_points"):
        make_shape("chair", 0, n_points=0)
    with pytest.raises(ValueError, match="non-negative"):
        make_shape("chair", 0, seed=-1)
    with pytest.raises(ValueError, match="n_shapes must be a positive number of shapes, got 0"):
        make_collection("chair", 0, use_cache=False)
    with pytest.raises(FileNotFoundError, match="no such collection"):
        ShapeCollection.load("/nonexistent/c.npz")


def test_plot_shapes_draws_one_panel_per_shape(samples):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = [samples["chair"][0], samples["animal"][0]]
    fig = shapes.plot_shapes(shown, titles=["a", "b"], ncols=2)
    assert len(fig.axes) == 2
    plt.close(fig)
