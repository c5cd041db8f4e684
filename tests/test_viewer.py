"""The grasp viewer (``ges view``): the scene it builds for a record, checked against the URDF and against PyBullet's
placement of the same hand; its server, browsing and hand toggle; the command; and the page drawn by headless
Chromium (installed with apt-get when missing and running as root, else skipped)."""

from __future__ import annotations

import dataclasses
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from ges_core.cli import main
from ges_core.contact import FINGER_SLOTS
from ges_core.dataset import DatasetWriter, SimVerdict, TrialVerdict
from ges_core.errors import AssetError, BackendUnavailable, ConfigError, UnknownNameError
from ges_core.registry import load_registry
from ges_core.render.base import OBJECT_COLOR
from ges_core.viewer import ViewerConfig, ViewerData, require_viser
from ges_core.viewer.app import PARTS
from ges_core.viewer.figures import record_markdown

REPO = Path(__file__).resolve().parent.parent
DATASET = REPO / "tests" / "data" / "dataset_v2"
"""Two objects (a box, a sphere), each with a Shadow and an Allegro record (written by a real Stage 1 run)."""
BOX = "procedural/box/000"


@pytest.fixture(scope="module")
def data() -> ViewerData:
    return ViewerData(DATASET)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# -- the scene, without a browser ------------------------------------------------------------------


@pytest.mark.parametrize("hand", ["shadow", "allegro"])
def test_scene_draws_each_urdf_shape_of_the_hand_twice(data, hand):
    """One mesh per <visual> of a link that has visuals, else per <collision>; at grasp and at pre-grasp."""
    view, note = data.hand_view(hand)
    assert note == ""
    root = ET.fromstring(view.kinematics.urdf_text)
    expected = 0
    for link in root.findall("link"):
        visuals = [v for v in link.findall("visual") if v.find("geometry") is not None]
        expected += len(visuals) if visuals else len(link.findall("collision"))
    scene = data.scene(BOX, hand)
    assert len(scene.group("/grasp/")) == expected > 10
    assert len(scene.group("/pregrasp/")) == expected
    assert {m.source for m in view.meshes} == ({"collision"} if hand == "shadow" else {"visual"})
    assert len(scene.group("/object")) == 1 and len(scene.group("/table")) == 1
    assert [m.name for m in scene.group("/contacts/")] == [f"/contacts/{s}" for s in FINGER_SLOTS]
    assert scene.notes == ()


@pytest.mark.parametrize("hand", ["shadow", "allegro"])
def test_hand_links_sit_where_pybullet_puts_them(data, hand):
    """The viewer places links by pytorch-kinematics FK; PyBullet's renderer, given the same record, places its
    own copy of the hand by its own kinematics: every drawn link's origin agrees, at grasp and (via FK) pre-grasp."""
    from ges_core.render import open_renderer

    registry = load_registry()
    record = data.record(BOX, hand)
    scene = data.scene(BOX, hand)
    view = data.hand_view(hand)[0]
    drawn = {m.name.split("/")[2]: m.position for m in scene.group("/grasp/")}
    with open_renderer(registry) as renderer:
        hand_model = registry.build_hand(hand)
        joints = dict(zip(record.joint_names, record.grasp.q, strict=True))
        renderer.render(None, None, hand_model, record.grasp.wrist_pose, joints)
        engine = renderer.link_positions(hand_model, list(drawn))
    np.testing.assert_allclose(np.array(list(drawn.values())), engine, atol=1e-5)
    base = view.kinematics.base_link
    pre = {m.name.split("/")[2]: m.position for m in scene.group("/pregrasp/")}
    np.testing.assert_allclose(pre[base], record.pregrasp.wrist_pose[:3], atol=1e-9)
    assert np.linalg.norm(pre[base] - drawn[base]) > 0.01  # the pre-grasp is backed off (0.02 m)


def test_contacts_normals_object_and_camera(data):
    record = data.record(BOX, "shadow")
    config = ViewerConfig(normal_length=0.04)
    scene = data.scene(BOX, "shadow", config)
    balls = scene.group("/contacts/")
    np.testing.assert_allclose([b.position for b in balls], record.contacts.positions, atol=1e-12)
    radius = np.linalg.norm(balls[0].vertices, axis=1)
    np.testing.assert_allclose(radius, config.contact_radius, rtol=1e-6)
    (normals,) = scene.lines
    np.testing.assert_allclose(normals.points[:, 1] - normals.points[:, 0], 0.04 * record.contacts.normals, atol=1e-12)
    obj = scene.group("/object")[0]
    assert obj.color == tuple(round(255 * c) for c in OBJECT_COLOR)
    size = obj.vertices.max(axis=0) - obj.vertices.min(axis=0)
    np.testing.assert_allclose(size, data.library().extents(BOX), rtol=1e-6)
    assert obj.vertices[:, 2].min() == pytest.approx(0.0, abs=1e-6)  # resting on the table plane
    inside = np.linalg.norm(record.contacts.positions - scene.center, axis=1) <= scene.radius + 1e-9
    assert inside.all() and 0.02 <= scene.radius < 0.3
    wrist_side = (record.grasp.wrist_pose[:2] - scene.center[:2]) @ scene.view_direction[:2]
    assert wrist_side < 0  # the camera looks from the side away from the wrist
    assert np.linalg.norm(scene.view_direction) == pytest.approx(1.0)


def test_what_cannot_be_drawn_becomes_a_note(tmp_path):
    def no_hands():
        raise UnknownNameError("hand", "shadow", ["allegro"])

    data = ViewerData(DATASET, registry=no_hands)
    scene = data.scene(BOX, "shadow")
    assert scene.group("/grasp/") == () and len(scene.group("/contacts/")) == 5
    assert any("hand 'shadow' not drawn: unknown hand 'shadow'" in n for n in scene.notes)


def test_failed_steps_and_foreign_joints_draw_what_exists(data):
    """A record whose contacts step failed has only the object; joints the hand lacks drop the hand with a note."""
    from ges_core.viewer import build_scene

    record = data.record(BOX, "allegro")
    mesh, view = data.object_mesh(BOX)[0], data.hand_view("allegro")[0]
    bare = dataclasses.replace(record, contacts=None, grasp=None, pregrasp=None)
    scene = build_scene(bare, object_mesh=mesh, hand=view)
    assert [m.name for m in scene.meshes] == ["/table", "/object"] and scene.lines == ()
    np.testing.assert_allclose(scene.center[:2], (mesh[0].min(axis=0) + mesh[0].max(axis=0))[:2] / 2, atol=1e-12)
    renamed = dataclasses.replace(record, joint_names=("joint_0.0_old", *record.joint_names[1:]))
    with pytest.raises(AssetError, match="hand 'allegro' has no joint.*joint_0.0_old.*another version"):
        build_scene(renamed, object_mesh=mesh, hand=view)
    fresh = ViewerData(DATASET)
    fresh._records[(BOX, "allegro")] = renamed  # as if the record had been made with another version of the hand
    scene = fresh.scene(BOX, "allegro")
    assert scene.group("/grasp/") == () and len(scene.group("/contacts/")) == 5
    assert "another version of this hand" in scene.notes[-1]


def test_not_a_dataset_and_empty_dataset_are_clear_errors(tmp_path, capsys):
    with pytest.raises(AssetError, match="is not a grasp dataset: it has no manifest.json"):
        ViewerData(tmp_path)
    with pytest.raises(AssetError, match="is not a folder"):
        ViewerData(tmp_path / "nope")
    empty = tmp_path / "empty"
    DatasetWriter(empty, {"run": 1}).close()
    with pytest.raises(AssetError, match="holds no grasp records .*ges demo"):
        ViewerData(empty)
    assert main(["view", str(empty), "--port", str(free_port())]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("ges: error: ges view: dataset ") and "no grasp records" in err[0]


def test_missing_viser_names_the_pip_command(monkeypatch):
    monkeypatch.setitem(sys.modules, "viser", None)  # import viser now raises ImportError
    with pytest.raises(BackendUnavailable, match=r"pip install 'ges-unigrasp\[view\]'"):
        require_viser()


def test_figures_say_outcome_steps_quality_and_each_verdict(data):
    record = data.record(BOX, "shadow")
    trials = (
        TrialVerdict(name="mass_x2", success=False, reason="dropped"),
        TrialVerdict(name="pose_1", success=True, reason="success"),
    )
    sapien = dataclasses.replace(record.validations["sapien"], trials=trials, robustness=0.5)
    text = record_markdown(dataclasses.replace(record, validations={**record.validations, "sapien": sapien}))
    assert "**procedural/box/000** · hand **shadow**" in text and "**success**" in text
    assert "robust trials 1/2 held (robustness 0.50): failed mass_x2 `dropped`" in text
    assert "**pybullet**: nominal trial held" in text and "**sapien** (primary)" in text
    fc = f"force closure ε {record.quality.force_closure:.3f}"
    assert fc in text and "| validation | ok |" in text
    steps = dict(record.steps)
    steps["validation"] = dataclasses.replace(steps["validation"], ok=False, reason="dropped")
    steps["robust"] = dataclasses.replace(steps["robust"], reason="skipped")
    verdict = SimVerdict(success=False, reason="dropped", flags={"held": False})
    failed = dataclasses.replace(record, steps=steps, validations={"sapien": verdict})
    text = record_markdown(failed)
    assert "**failed** at validation: `dropped`" in text and "| validation | ✗ dropped |" in text
    assert "nominal trial ✗ `dropped` · held ✗" in text


# -- the server: browsing and the hand toggle -------------------------------------------------------


@pytest.fixture(scope="module")
def viewer():
    pytest.importorskip("viser", reason="the viewer's server needs viser: pip install 'ges-unigrasp[view]'")
    from ges_core.viewer import start

    v = start(DATASET, port=free_port(), initial=(BOX, "shadow"))
    yield v
    v.server.stop()


def test_browsing_and_the_hand_toggle(viewer):
    assert viewer.shown == (BOX, "shadow")
    with urllib.request.urlopen(viewer.url, timeout=30) as page:
        assert b"<html" in page.read().lower()
    object_handle = viewer._handles["/object"][0]
    viewer.other_hand()  # same object, the other hand: object kept (moved, not sent again), hand replaced
    assert viewer.shown == (BOX, "allegro")
    assert viewer._handles["/object"][0] is object_handle
    assert len([n for n in viewer._handles if n.startswith("/grasp/")]) == len(viewer.scene.group("/grasp/"))
    assert "hand **allegro**" in viewer._figures.content
    viewer.step(+1)  # next object keeps the hand
    assert viewer.shown == ("procedural/sphere/000", "allegro")
    assert viewer._handles["/object"][0] is not object_handle
    viewer.set_visible("hand at pre-grasp", False)
    assert not any(h.visible for n, (h, _) in viewer._handles.items() if n.startswith("/pregrasp/"))
    assert all(h.visible for n, (h, _) in viewer._handles.items() if n.startswith("/grasp/"))
    viewer.set_visible("hand at pre-grasp", True)
    viewer.show(BOX, "shadow")


def test_unknown_first_record_is_named(tmp_path):
    pytest.importorskip("viser", reason="the viewer's server needs viser: pip install 'ges-unigrasp[view]'")
    from ges_core.viewer import start

    with pytest.raises(UnknownNameError, match="unknown object 'procedural/box/999' in dataset"):
        start(DATASET, port=free_port(), initial=("procedural/box/999", None))
    with pytest.raises(ConfigError, match="no record of object 'procedural/box/000' with hand 'ability'"):
        start(DATASET, port=free_port(), initial=(BOX, "ability"))


def test_command_prints_the_url_and_stops_on_ctrl_c():
    pytest.importorskip("viser", reason="the viewer's server needs viser: pip install 'ges-unigrasp[view]'")
    port = free_port()
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "ges_core.cli", "view", str(DATASET), "--port", str(port)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=REPO)
    watchdog = threading.Timer(120, proc.kill)  # a server that never prints its URL fails the test, not hangs it
    watchdog.start()
    try:
        line = ""
        while "ges view:" not in line:
            line = proc.stdout.readline()
            assert line or proc.poll() is None, proc.stderr.read()
        assert f"4 records of {DATASET} at http://127.0.0.1:{port}" in line
        with urllib.request.urlopen(f"http://127.0.0.1:{port}", timeout=30) as page:
            assert page.status == 200
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0  # under pytest-xdist SIGINT arrives ignored: serve() restores it
        assert "ges view: stopped" in proc.stdout.read()
    finally:
        watchdog.cancel()
        if proc.poll() is None:
            proc.kill()
            proc.wait()


# -- the page in headless Chromium -------------------------------------------------------------------


@pytest.fixture(scope="module")
def chromium() -> str:
    """A Chromium executable; installed with apt-get (Debian package ``chromium``) when missing and root."""
    from ges_core.viewer.chromium import find_chromium

    if find_chromium() is None and hasattr(os, "geteuid") and os.geteuid() == 0 and shutil.which("apt-get"):
        install = ["apt-get", "install", "-y", "-q", "chromium"]
        env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
        if subprocess.run(install, capture_output=True, env=env, timeout=900).returncode != 0:
            subprocess.run(["apt-get", "update", "-q"], capture_output=True, env=env, timeout=600)
            subprocess.run(install, capture_output=True, env=env, timeout=900)
    exe = find_chromium()
    if exe is None:
        pytest.skip("headless Chromium is not installed and could not be (needs root and apt-get: apt-get install "
                    "chromium; or set GES_CHROMIUM to a Chromium executable)")  # fmt: skip
    return exe


def wait_for(page, ok, timeout: float = 90.0) -> tuple[np.ndarray, dict[str, int]]:
    """Screenshots until ``ok(counts)`` (or the timeout: the last one); counts: :func:`canvas_pixels`."""
    from ges_core.viewer.chromium import canvas_pixels

    deadline = time.monotonic() + timeout
    while True:
        rgb = page.screenshot()
        counts = canvas_pixels(rgb)
        if ok(counts) or time.monotonic() > deadline:
            return rgb, counts
        time.sleep(0.2)


@pytest.mark.slow
def test_page_in_headless_chromium_shows_the_scene(chromium, viewer, tmp_path):
    """The canvas shows the object and the hand; with every part hidden the same page shows the empty viser scene
    (background only). Each screenshot takes 0.1-5 s (up to 25 s on a loaded 2-core machine): two phases only."""
    from PIL import Image

    from ges_core.viewer.chromium import VIEWER_PANEL_PX, HeadlessPage

    viewer.show(BOX, "shadow")
    size = (960, 600)
    area = (size[0] - VIEWER_PANEL_PX) * size[1]
    try:
        with HeadlessPage(size=size) as page:
            page.navigate(viewer.url)
            rgb, shown = wait_for(page, lambda c: c["object"] > 300 and c["hand"] > 3000)
            Image.fromarray(rgb).save(tmp_path / "viewer.png")  # kept for a look when an assert fails
            assert shown["scene"] > 0.05 * area and shown["object"] > 300 and shown["hand"] > 3000, shown
            for part in PARTS:
                viewer.set_visible(part, False)
            rgb, empty = wait_for(page, lambda c: c["scene"] < 0.002 * area)
            Image.fromarray(rgb).save(tmp_path / "empty.png")
            assert empty["scene"] < 0.002 * area and empty["object"] == empty["hand"] == 0, (shown, empty)
    finally:
        for part in PARTS:
            viewer.set_visible(part, True)


def test_browsing_by_split(tmp_path):
    """A dataset with the box in 'train' and the sphere in 'unseen_object': the split lists and the viewer follow."""
    source = ViewerData(DATASET).dataset
    with DatasetWriter(tmp_path / "ds", source.run_config) as writer:
        for record in source:
            split = "train" if record.object_id == BOX else "unseen_object"
            writer.add(dataclasses.replace(record, split=split, run_config_hash=None))
    data = ViewerData(tmp_path / "ds")
    assert data.splits() == ["train", "unseen_object"]
    assert data.objects("unseen_object") == ["procedural/sphere/000"] and data.objects("train") == [BOX]
    assert data.objects() == [BOX, "procedural/sphere/000"] and data.hands(BOX) == ["allegro", "shadow"]
    pytest.importorskip("viser", reason="the viewer's server needs viser: pip install 'ges-unigrasp[view]'")
    from ges_core.viewer import start

    viewer = start(tmp_path / "ds", port=free_port(), initial=(BOX, "shadow"))
    try:
        viewer._split.value = "unseen_object"
        viewer._on_split()  # what the dropdown's callback runs
        assert viewer.shown == ("procedural/sphere/000", "shadow")
        viewer.step(+1)  # the only object of the split: stays
        assert viewer.shown == ("procedural/sphere/000", "shadow")
        assert viewer._object.options == ("procedural/sphere/000",)
        assert "object 1 of 1 · also: allegro (same contacts)" in viewer._position.content
    finally:
        viewer.server.stop()


def test_canvas_pixels_tells_object_hand_and_background_apart():
    from ges_core.render.base import HAND_COLOR
    from ges_core.viewer.chromium import VIEWER_PANEL_PX, canvas_pixels

    rgb = np.full((600, 960, 3), 255, dtype=np.uint8)
    rgb[300:320, 400:450] = [round(255 * c) for c in OBJECT_COLOR]  # 1000 object pixels
    rgb[400:420, 400:500] = [round(255 * c) for c in HAND_COLOR]  # 2000 hand pixels
    rgb[500:510, 400:500] = 235  # 1000 table-grey pixels: scene, neither object nor hand
    rgb[:, 960 - VIEWER_PANEL_PX :] = [20, 20, 200]  # the side panel is not canvas
    assert canvas_pixels(rgb) == {"scene": 4000, "object": 1000, "hand": 2000}
