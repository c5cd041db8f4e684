"""Grasp pictures: the renderer a simulator plugin offers (PyBullet's TinyRenderer), found through the
registry, drawing object, contacts and hand; and contact sheets."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from ges_core.contact import FINGER_SLOTS, ContactSet
from ges_core.errors import AssetError, BackendUnavailable, UnknownNameError
from ges_core.objects.asset import ObjectAsset
from ges_core.objects.simple import box_asset
from ges_core.registry import load_registry
from ges_core.render import (
    HAND_COLOR,
    OBJECT_COLOR,
    SLOT_COLORS,
    RenderConfig,
    Renderer,
    contact_sheet,
    open_renderer,
    read_png,
    render_grasp,
    render_record,
    write_png,
)
from ges_core.render.png import tile_origin
from ges_core.synthesis.types import Grasp
from ges_plugins.sims.pybullet.render import PybulletRenderer

REGISTRY = load_registry()

HALF = np.array([0.025, 0.035, 0.05])
"""Half extents of the test box, metres (bottom face on the table)."""
VISIBLE_CONTACTS = np.array(  # on the -y and +x faces and the top, which the default camera sees
    [[0.0, -HALF[1], 0.05], [HALF[0], -0.02, 0.08], [HALF[0], 0.0, 0.05], [HALF[0], 0.02, 0.02], [-0.01, 0.0, 0.1]]
)
VISIBLE_NORMALS = np.array([[0, -1, 0], [1, 0, 0], [1, 0, 0], [1, 0, 0], [0, 0, 1]], dtype=float)


@pytest.fixture(scope="module")
def hands():
    return {name: REGISTRY.build_hand(name) for name in ("shadow", "allegro")}


@pytest.fixture(scope="module")
def box() -> ObjectAsset:
    return box_asset(tuple(HALF), object_id="test/box")


def renderer_with(config: RenderConfig | None = None) -> Renderer:
    """The registry's renderer (the first simulator that offers one: PyBullet's)."""
    return open_renderer(REGISTRY, config)


@pytest.fixture(scope="module")
def renderer():
    with renderer_with() as r:
        yield r


def top_grasp(hand) -> Grasp:
    """Palm down over the box with the fingers 60 % closed (the sim-check pose)."""
    from ges_core.sim_check import grasp_start_pose

    base = grasp_start_pose(hand, np.array([0.0, 0.0, HALF[2]]), 0.6)
    return Grasp(hand=hand.name, wrist_pose=base, q=hand.description.closed_pose(0.6))


def slot_pixels(rgb: np.ndarray, color: tuple[float, float, float], min_cos: float = 0.995) -> int:
    """Pixels whose colour points the way ``color`` does (shading scales a colour, it keeps its direction)."""
    pix = rgb.reshape(-1, 3).astype(float)
    c = np.asarray(color) / np.linalg.norm(color)
    norms = np.linalg.norm(pix, axis=1)
    cos = (pix @ c) / np.maximum(norms, 1e-9)
    return int(((cos > min_cos) & (norms > 60)).sum())


def contacts() -> ContactSet:
    return ContactSet(VISIBLE_CONTACTS, VISIBLE_NORMALS, "test/box")


# --- finding a renderer ---------------------------------------------------------------------------
def test_the_registry_builds_the_renderer_a_simulator_offers():
    small = RenderConfig(size=(64, 48))
    with open_renderer(REGISTRY) as first, open_renderer(REGISTRY, small, sim="pybullet") as named:
        assert isinstance(first, PybulletRenderer) and isinstance(named, PybulletRenderer)
        assert named.config.size == (64, 48) and first.config == RenderConfig()
        assert named.render(None).shape == (48, 64, 3)


def test_no_renderer_says_which_simulators_offer_one():
    builtins = load_registry(autoload=False)  # installed outside simulators (ges-mujoco-sim) would join the lists
    with pytest.raises(BackendUnavailable, match="simulator 'sapien' offers no renderer .*; those that do: pybullet"):
        builtins.build_renderer("sapien")
    with pytest.raises(UnknownNameError, match="unknown sim 'pybulet'. Did you mean 'pybullet'"):
        builtins.build_renderer("pybulet")
    without = load_registry(blocked=("pybullet",), autoload=False)
    with pytest.raises(BackendUnavailable, match=r"no simulator plugin offers a renderer .* \(simulators: sapien\)"):
        open_renderer(without)


# --- pictures -----------------------------------------------------------------------------------


@pytest.mark.parametrize("hand_name", ["shadow", "allegro"])
def test_grasp_picture_shows_object_contacts_and_hand(tmp_path, hands, box, hand_name):
    hand = hands[hand_name]
    start = time.perf_counter()
    fixed_view = renderer_with(RenderConfig(away_from_base=None))  # the view VISIBLE_CONTACTS are placed for
    path = render_grasp(hand, box, contacts(), top_grasp(hand), tmp_path / "grasp.png", renderer=fixed_view)
    seconds = time.perf_counter() - start
    print(f"{hand_name}: one 320x240 picture with a fresh renderer in {seconds:.3f} s")
    with Image.open(path) as image:  # read back by Pillow, independently of our reader
        assert image.format == "PNG" and image.size == (320, 240)
        rgb = np.asarray(image.convert("RGB"))
    assert rgb.std() > 20  # not blank
    for slot in FINGER_SLOTS:  # markers under a see-through finger mix with its grey, hence 0.98
        assert slot_pixels(rgb, SLOT_COLORS[slot], 0.98) >= 10, slot
    bare = read_png(render_grasp(hand, box, None, top_grasp(hand), tmp_path / "bare.png", renderer=fixed_view))
    fixed_view.close()  # bare: the negative control
    assert all(slot_pixels(bare, SLOT_COLORS[s], 0.98) == 0 for s in FINGER_SLOTS)


def test_camera_looks_from_the_side_away_from_the_forearm(hands, box):
    """The Shadow's base (forearm, 29 cm behind the palm) turned toward the default camera hides most of the box
    from the fixed view; looking from the side away from the base shows it."""
    from ges_core.transforms import matrix_to_pose, pose_to_matrix

    hand = hands["shadow"]
    grasp = top_grasp(hand)
    base = pose_to_matrix(grasp.wrist_pose)
    toward = np.radians(RenderConfig().azimuth_deg) - np.arctan2(base[1, 3], base[0, 3])  # forearm -> camera
    turn = np.eye(4)
    turn[:2, :2] = [[np.cos(toward), -np.sin(toward)], [np.sin(toward), np.cos(toward)]]
    facing = matrix_to_pose(turn @ base)  # the grasp turned about the box's vertical axis
    joints = dict(zip(hand.description.joint_names, grasp.q, strict=True))
    seen = {}
    for away in (None, 30.0):
        with renderer_with(RenderConfig(away_from_base=away, hand_opacity=1.0)) as r:
            seen[away] = slot_pixels(r.render(box, None, hand, facing, joints), OBJECT_COLOR, 0.998)
    assert seen[30.0] > 2 * seen[None] + 100, seen


def test_hand_alone_is_drawn_where_its_links_are(hands, renderer, box):
    """Opaque hand, no object: many pixels carry the hand's colour; an object-only picture has none."""
    hand = hands["allegro"]
    grasp = top_grasp(hand)
    joints = dict(zip(hand.description.joint_names, grasp.q, strict=True))
    with renderer_with(RenderConfig(hand_opacity=1.0)) as opaque:
        rgb = opaque.render(None, None, hand, grasp.wrist_pose, joints)
        only_object = opaque.render(box)
    assert slot_pixels(rgb, HAND_COLOR, 0.998) > 0.05 * rgb.shape[0] * rgb.shape[1]
    assert slot_pixels(only_object, HAND_COLOR, 0.998) < 0.001 * rgb.shape[0] * rgb.shape[1]


@pytest.mark.parametrize("hand_name", ["shadow", "allegro"])
def test_hand_links_sit_where_the_kinematics_put_them(hands, renderer, box, hand_name):
    """PyBullet's drawn hand against pytorch-kinematics FK composed with the wrist pose."""
    _check_drawn_links(renderer, box, hands[hand_name])


def test_a_hand_with_glb_meshes_is_drawn(renderer, box, tmp_path):
    """A hand whose URDF names a ``.glb`` mesh (PyBullet's loader refuses the file: "invalid mesh filename
    extension") is drawn from the URDF the PyBullet backend loads (the OBJ copy), where FK puts its links."""
    from ges_core.hand_files import FileHand

    from helpers_hands import write_l_palm_hand

    yaml = write_l_palm_hand(tmp_path, ".glb")
    hand = FileHand(yaml, yaml.with_suffix(".urdf"), strict=False)
    assert ".glb" in hand.urdf_text()
    _check_drawn_links(renderer, box, hand)


def _check_drawn_links(renderer, box, hand) -> None:
    from ges_core.kinematics import HandKinematics
    from ges_core.transforms import pose_to_matrix

    hand_name = hand.name
    d = hand.description
    grasp = top_grasp(hand)
    renderer.render(box, contacts(), hand, grasp.wrist_pose, dict(zip(d.joint_names, grasp.q, strict=True)))
    links = [d.base_link, d.wrist.link, *d.tip_links]
    drawn = renderer.link_positions(hand, links)
    fk = HandKinematics.from_hand(hand).link_poses(torch.as_tensor(grasp.q[None]), links)[0].numpy()
    expected = (pose_to_matrix(grasp.wrist_pose) @ fk)[:, :3, 3]
    np.testing.assert_allclose(drawn, expected, atol=1e-5)
    with pytest.raises(UnknownNameError, match=f"unknown link 'nope' in the URDF of hand '{hand_name}'"):
        renderer.link_positions(hand, ["nope"])


def test_size_is_configurable_and_checked(tmp_path, box):
    path = render_grasp(None, box, contacts(), None, tmp_path / "small.png", size=(160, 120))
    assert read_png(path).shape == (120, 160, 3)
    with pytest.raises(ValueError, match=r"picture size must be two integers >= 8 \(width, height\), got \(4, 4\)"):
        RenderConfig(size=(4, 4))
    with pytest.raises(ValueError, match=r"hand_opacity must lie in \[0, 1\], got 2"):
        RenderConfig(hand_opacity=2)


def test_hidden_contacts_are_drawn_faintly(box):
    """A contact behind the box still shows (at half strength); with strength 0 it disappears."""
    positions, normals = VISIBLE_CONTACTS * [-1, -1, 1], VISIBLE_NORMALS * [-1, -1, 1]  # onto the +y and -x faces
    positions[4], normals[4] = [0.01, HALF[1], 0.03], [0, 1, 0]  # off the top, which the camera sees
    far = ContactSet(positions, normals, "test/box")
    short = 0.003  # normal sticks that stay inside the balls, so nothing pokes out past the box
    with renderer_with(RenderConfig(normal_length=short)) as r:
        faint = r.render(box, far)
    with renderer_with(RenderConfig(normal_length=short, hidden_contact_opacity=0.0)) as r:
        none = r.render(box, far)
        visible = r.render(box, contacts())
    assert (np.abs(faint.astype(int) - none).sum(axis=2) > 30).sum() > 20
    assert all(slot_pixels(none, SLOT_COLORS[s], 0.98) == 0 for s in FINGER_SLOTS)
    assert all(slot_pixels(visible, SLOT_COLORS[s]) >= 20 for s in FINGER_SLOTS)  # visible ones at full strength


def test_record_pictures_match_joints_by_name(tmp_path, hands, box, renderer):
    """A record whose joints are stored in reverse order draws the same picture."""
    from ges_core.dataset import STEPS, GraspRecord, HandPose, StepOutcome

    hand = hands["shadow"]
    grasp = top_grasp(hand)
    names = hand.description.joint_names
    record = GraspRecord(
        object_id="test/box",
        category="box",
        split="train",
        hand="shadow",
        simulator="pybullet",
        joint_names=tuple(reversed(names)),
        steps={s: StepOutcome(ok=True) for s in STEPS},
        contacts=contacts(),
        grasp=HandPose(grasp.wrist_pose, grasp.q[::-1]),
        grasp_stage="refinement",
    )
    a = read_png(render_record(record, hand, box, tmp_path / "record.png", renderer=renderer))
    b = read_png(render_grasp(hand, box, contacts(), grasp, tmp_path / "grasp.png", renderer=renderer))
    assert np.array_equal(a, b)


def test_picture_errors_say_what_is_wrong(tmp_path, hands, box, renderer):
    hand = hands["allegro"]
    with pytest.raises(UnknownNameError, match=r"unknown joint 'nope' in the URDF of hand 'allegro' \("):
        renderer.render(box, None, hand, top_grasp(hand).wrist_pose, {"nope": 0.1})
    with pytest.raises(ValueError, match="render needs both a hand and its wrist_pose, or neither"):
        renderer.render(box, None, hand)
    with pytest.raises(ValueError, match=r"render_grasp: a grasp needs its hand \(got hand=None\)"):
        render_grasp(None, box, None, top_grasp(hand), tmp_path / "x.png")
    missing = ObjectAsset(object_id="test/missing", category="box", mesh_path=tmp_path / "none.obj", collision=())
    with pytest.raises(AssetError, match=r"object 'test/missing': cannot draw it: cannot read mesh .*none.obj"):
        renderer.render(missing)
    (tmp_path / "empty.obj").write_text("# no vertices\n")
    empty = ObjectAsset(object_id="test/empty", category="box", mesh_path=tmp_path / "empty.obj", collision=())
    with pytest.raises(AssetError, match=r"object 'test/empty': cannot draw it: .*empty.obj"):
        renderer.render(empty)


def test_render_timing(renderer, hands, box):
    """Reported in the closing note: seconds per 320 x 240 picture with a reused renderer."""
    for name, hand in hands.items():
        grasp = top_grasp(hand)
        joints = dict(zip(hand.description.joint_names, grasp.q, strict=True))
        renderer.render(box, contacts(), hand, grasp.wrist_pose, joints)  # loads the hand
        start = time.perf_counter()
        for _ in range(3):
            renderer.render(box, contacts(), hand, grasp.wrist_pose, joints)
        per_picture = (time.perf_counter() - start) / 3
        print(f"{name}: {per_picture:.3f} s per picture (object, contacts, hand; three TinyRenderer passes)")
        assert per_picture < 2.0


# --- PNG files and contact sheets ---------------------------------------------------------------


def _tiles(tmp_path: Path, n: int, size: tuple[int, int] = (32, 24)) -> list[Path]:
    rng = np.random.default_rng(0)
    return [
        write_png(tmp_path / f"t{i}.png", rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)) for i in range(n)
    ]


def test_contact_sheet_tiles_row_by_row(tmp_path):
    paths = _tiles(tmp_path, 5)
    frames = [(0, 200, 0), (200, 0, 0), (0, 200, 0), (0, 0, 200), (9, 9, 9)]
    sheet = read_png(contact_sheet(paths, tmp_path / "sheet.png", columns=2, gap=4, frame_colors=frames))
    assert sheet.shape == (4 + 3 * (24 + 4), 4 + 2 * (32 + 4), 3)  # 3 rows of 2 columns
    for i, p in enumerate(paths):
        y, x = tile_origin(i, 2, (24, 32), 4)
        assert (y, x) == (4 + (i // 2) * 28, 4 + (i % 2) * 36)
        assert np.array_equal(sheet[y : y + 24, x : x + 32], read_png(p))
        assert tuple(sheet[y - 1, x - 1]) == frames[i]
    assert tuple(sheet[-2, -2]) == (255, 255, 255)  # the empty sixth cell stays white


def test_contact_sheet_labels_and_resizing(tmp_path):
    paths = _tiles(tmp_path, 2) + _tiles(tmp_path / "big", 1, size=(64, 48))
    sheet = read_png(contact_sheet(paths, tmp_path / "sheet.png", columns=3, labels=["a", "b", "c"]))
    assert sheet.shape == (4 + 24 + 16 + 4, 4 + 3 * (32 + 4), 3)  # one row, label strip included
    y, x = tile_origin(2, 3, (24, 32), 4, 16)
    with Image.open(paths[2]) as big:
        expected = np.asarray(big.convert("RGB").resize((32, 24)))
    assert np.array_equal(sheet[y : y + 24, x : x + 32], expected)
    strip = sheet[y + 24 + 4 : y + 24 + 16, 4 : 4 + 32]
    assert (strip.sum(axis=2) < 200).any()  # the label's dark text


def test_contact_sheet_and_png_errors(tmp_path):
    paths = _tiles(tmp_path, 2)
    with pytest.raises(ValueError, match="contact_sheet needs at least one picture"):
        contact_sheet([], tmp_path / "s.png")
    with pytest.raises(ValueError, match="contact_sheet needs columns >= 1, got 0"):
        contact_sheet(paths, tmp_path / "s.png", columns=0)
    with pytest.raises(ValueError, match="contact_sheet got 1 labels for 2 pictures"):
        contact_sheet(paths, tmp_path / "s.png", labels=["x"])
    with pytest.raises(AssetError, match=r"cannot read picture .*nothing.png"):
        contact_sheet([tmp_path / "nothing.png"], tmp_path / "s.png")
    with pytest.raises(
        ValueError, match=r"write_png needs an \(H, W, 3\) uint8 array, got shape \(4, 4\) dtype float64"
    ):
        write_png(tmp_path / "x.png", np.zeros((4, 4)))


def test_a_picture_that_cannot_be_drawn_costs_the_picture_not_the_record(tmp_path, hands, box, caplog):
    """The Stage 1 worker: a renderer plugin's own error (not only a storage error) leaves the record without its
    picture, says why in ``errors["picture"]`` and warns once per process; the run goes on."""
    from types import SimpleNamespace

    from test_dataset import make_record

    from ges_core.synthesis.run import worker

    class RefusingRenderer:
        def render(self, *args, **kwargs):
            raise RuntimeError("Cannot load URDF file.")

    library = SimpleNamespace(get=lambda object_id: box)
    state = worker._State(
        context=SimpleNamespace(pictures=tmp_path), registry=REGISTRY, library=library, renderer=RefusingRenderer()
    )
    state.hands["shadow"] = hands["shadow"]
    records = [make_record(f"procedural/box/00{i}", picture=None) for i in range(2)]
    with caplog.at_level("WARNING"):
        out = [worker._with_picture(state, r) for r in records]
    assert [r.picture for r in out] == [None, None]
    assert [r.errors["picture"] for r in out] == ["drawing failed: RuntimeError: Cannot load URDF file."] * 2
    assert [m for m in caplog.messages if "without their pictures" in m] == [
        "ges: warning: drawing failed: RuntimeError: Cannot load URDF file. (the records are saved without their "
        "pictures)"
    ]
    assert not list(tmp_path.rglob("*.png"))
