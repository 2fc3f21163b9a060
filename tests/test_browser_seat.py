"""The browser seat without a browser: the device's semantics, the session's loop and recording, and the web app as
a websocket client meets it (tokens, roles, bad messages, silence). The page itself: test_browser_page.py."""

import json
import time
import urllib.error
import urllib.request

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.teleop import KeyboardDevice
from dvrl_marl.teleop.browser import BROWSER_KEYS, BadMessage, BrowserDevice, TeleopLost


class FakeClock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


# --- the device ------------------------------------------------------------------------------------------------
def test_device_is_lost_until_a_page_connects_and_when_it_goes_silent():
    clock = FakeClock()
    device = BrowserDevice(silence_timeout=1.0, clock=clock)
    with pytest.raises(TeleopLost):
        device.action(None)
    device.connect()
    assert not device.lost
    clock.now = 0.9
    device.handle({"type": "ping"})
    clock.now = 1.8  # 0.9 s after the ping
    assert not device.lost
    clock.now = 2.0  # 1.1 s of silence
    assert device.lost
    with pytest.raises(TeleopLost):
        device.action(None)
    device.handle({"type": "ping"})  # the page is back
    assert not device.lost
    device.disconnect()
    assert device.lost


def test_keys_have_the_keyboard_devices_meaning():
    device, keyboard = BrowserDevice(), KeyboardDevice()
    device.connect()
    script = [("KeyD", True), ("KeyW", True), ("ShiftLeft", True), ("Space", True), ("Space", False),
              ("ShiftLeft", False), ("KeyD", False), ("KeyR", True), ("KeyF", True), ("KeyW", False)]
    for code, down in script:
        device.handle({"type": "key", "code": code, "down": down})
        keyboard.key_event(BROWSER_KEYS[code], 1 if down else 0)
        np.testing.assert_array_equal(device.action(None), keyboard.action(None))


def test_gamepad_sticks_add_to_keys_and_its_button_toggles_the_jaw():
    device = BrowserDevice()
    device.connect()
    device.handle({"type": "gamepad", "axes": [0.5, -0.25, 0.0], "toggle": False})
    np.testing.assert_allclose(device.action(None), [0.5, -0.25, 0.0, 1.0])
    device.handle({"type": "key", "code": "KeyD", "down": True})
    np.testing.assert_allclose(device.action(None), [1.0, -0.25, 0.0, 1.0])  # clipped to the action range
    device.handle({"type": "gamepad", "axes": [0.0, 0.0, 0.0], "toggle": True})
    np.testing.assert_allclose(device.action(None), [1.0, 0.0, 0.0, -1.0])


def test_a_page_that_leaves_releases_its_keys_but_not_the_jaw():
    device = BrowserDevice()
    device.connect()
    device.handle({"type": "key", "code": "KeyD", "down": True})
    device.handle({"type": "key", "code": "Space", "down": True})
    device.handle({"type": "gamepad", "axes": [0.0, 1.0, 0.0]})
    device.disconnect()
    device.connect()
    np.testing.assert_array_equal(device.action(None), [0.0, 0.0, 0.0, -1.0])


@pytest.mark.parametrize("message, reason", [
    ([1, 2], "JSON object"),
    ({"type": "jump"}, "unknown message type"),
    ({"type": "key", "code": "KeyQ", "down": True}, "unknown key code"),
    ({"type": "key", "code": "KeyD", "down": "yes"}, "'down'"),
    ({"type": "gamepad", "axes": [0, 0]}, "'axes'"),
    ({"type": "gamepad", "axes": [0, 2.0, 0]}, "'axes'"),
    ({"type": "gamepad", "axes": [0, float("nan"), 0]}, "'axes'"),
    ({"type": "gamepad", "axes": [0, 0, 0], "toggle": 1}, "'toggle'"),
    ({"type": "ping", "seq": -1}, "'seq'"),
])
def test_bad_messages_are_refused_with_the_reason(message, reason):
    device = BrowserDevice()
    device.connect()
    with pytest.raises(BadMessage, match=reason):
        device.handle(message)
    np.testing.assert_array_equal(device.action(None), [0.0, 0.0, 0.0, 1.0])  # nothing changed


json_values = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=12),
                           lambda children: st.lists(children, max_size=4)
                           | st.dictionaries(st.text(max_size=8), children, max_size=4), max_leaves=12)


@settings(max_examples=300, deadline=None)
@given(message=json_values | st.fixed_dictionaries({"type": st.sampled_from(["key", "gamepad", "ping"])},
                                                   optional={"code": json_values, "down": json_values,
                                                             "axes": json_values, "toggle": json_values,
                                                             "seq": json_values}))
def test_any_message_is_used_or_refused_and_the_action_stays_in_range(message):
    device = BrowserDevice()
    device.connect()
    try:
        device.handle(message)
    except BadMessage:
        pass
    action = device.action(None)
    assert action.shape == (4,) and action.dtype == np.float32
    assert np.all(np.isfinite(action)) and np.all(np.abs(action) <= 1.0)


def test_in_the_scene_a_lost_browser_holds_the_seat_and_says_so():
    device = BrowserDevice()
    env = suction_debris_v8.parallel_env(surgeon=device)
    env.reset(seed=3)
    start = env.view.progress()["tips"]["grasper"]
    for _ in range(10):
        _, _, _, _, infos = env.step({"suction": np.zeros(4, np.float32)})
        assert infos["suction"]["teleop_lost"]
    assert env.view.progress()["tips"]["grasper"] == start
    device.connect()
    device.handle({"type": "key", "code": "KeyD", "down": True})
    _, _, _, _, infos = env.step({"suction": np.zeros(4, np.float32)})
    assert "teleop_lost" not in infos["suction"]
    assert env.view.progress()["tips"]["grasper"][0] > start[0]
    env.close()


# --- the session (no web) ------------------------------------------------------------------------------------------
minari = pytest.importorskip("minari", reason='recording needs Minari: pip install "dvrl-marl[data]"')


@pytest.fixture
def minari_store(tmp_path, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    return tmp_path / "minari"


def latest_status(session):
    from dvrl_marl.teleop.session import unpack_frame

    number, payload = session.latest()
    return (unpack_frame(payload)[0] if payload else None), number


def wait_for(predicate, session, timeout=20.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        status, _ = latest_status(session)
        if status is not None and predicate(status):
            return status
        time.sleep(0.01)
    raise AssertionError(f"timed out; last status {latest_status(session)[0]}")


def test_a_session_waits_for_the_person_runs_in_real_time_and_records_an_episode_that_replays(minari_store):
    from dvrl_marl import datasets
    from dvrl_marl.teleop.session import TeleopSession

    session = TeleopSession(partner="scripted", seed=11, max_cycles=120, dataset_id="dvrl_marl/surgeon-unit-v1",
                            silence_timeout=60.0)  # nobody pings here
    session.start()
    waiting = wait_for(lambda s: s["state"] == "waiting", session)
    assert waiting["teleop_lost"] and waiting["step"] == 0 and waiting["recording"]
    time.sleep(0.3)
    assert latest_status(session)[0]["step"] == 0  # nothing moves before the person starts
    session.device.connect()
    session.device.handle({"type": "key", "code": "KeyD", "down": True, "seq": 7})
    began = time.monotonic()
    session.begin()
    over = wait_for(lambda s: s["state"] == "over", session)
    elapsed = time.monotonic() - began
    assert over["step"] == 120 and not over["success"]
    assert elapsed >= 120 * 0.02 - 0.05, "a person's episode must not run faster than the 50 Hz control rate"
    assert over["input_seq"] == 7 and over["teleop_lost"] is False
    assert over["tip_mm"][0] > waiting["tip_mm"][0] + 10
    saved = session.close()
    assert [d["id"] for d in saved] == ["dvrl_marl/surgeon-unit-v1"] and saved[0]["episodes"] == 1
    dataset = minari.load_dataset("dvrl_marl/surgeon-unit-v1")
    episode = next(dataset.iterate_episodes())
    assert len(episode.actions) == 120 and bool(episode.truncations[-1])
    assert not np.any(episode.infos["teleop_lost"])
    np.testing.assert_allclose(episode.actions[:, 0], 1.0)
    result = datasets.replay(dataset, 0)
    assert result["max_observation_difference"] == 0.0 and result["steps"] == 120


def test_a_silent_device_holds_the_seat_in_the_session_and_the_recording_says_so(minari_store):
    from dvrl_marl.teleop.session import TeleopSession

    session = TeleopSession(partner="scripted", seed=2, max_cycles=60, realtime=False, silence_timeout=0.2,
                            dataset_id="dvrl_marl/surgeon-silent-v1")
    session.start()
    wait_for(lambda s: s["state"] == "waiting", session)
    session.begin()  # nobody connected: the whole episode holds still
    over = wait_for(lambda s: s["state"] == "over", session)
    assert over["teleop_lost"]
    session.close()
    episode = next(minari.load_dataset("dvrl_marl/surgeon-silent-v1").iterate_episodes())
    assert np.all(episode.infos["teleop_lost"][1:])
    np.testing.assert_array_equal(episode.actions[:, :3], 0.0)
    np.testing.assert_array_equal(episode.actions[:, 3], 1.0)  # the jaw as it was at reset: open


def test_stopping_the_recording_writes_a_dataset_and_later_ones_take_the_next_version(minari_store):
    from dvrl_marl.teleop.session import TeleopSession

    session = TeleopSession(partner="scripted", seed=0, max_cycles=40, realtime=False,
                            dataset_id="dvrl_marl/surgeon-stop-v1")
    session.start()
    wait_for(lambda s: s["state"] == "waiting", session)
    session.begin()
    wait_for(lambda s: s["state"] == "over", session)
    session.reset()
    wait_for(lambda s: s["state"] == "waiting" and s["episode"] == 1, session)
    session.begin()
    wait_for(lambda s: s["step"] >= 10, session)
    session.set_recording(False)  # mid-episode: kept as a stopped (truncated) episode
    wait_for(lambda s: s["saved"], session)
    session.set_recording(True)
    session.reset()
    wait_for(lambda s: s["episode"] == 2 and s["recording"], session)
    session.begin()
    wait_for(lambda s: s["state"] == "over", session)
    saved = session.close()
    assert [(d["id"], d["episodes"]) for d in saved] == [("dvrl_marl/surgeon-stop-v1", 2),
                                                          ("dvrl_marl/surgeon-stop-v2", 1)]
    first = list(minari.load_dataset("dvrl_marl/surgeon-stop-v1").iterate_episodes())
    assert len(first[0].actions) == 40 and 10 <= len(first[1].actions) < 40 and bool(first[1].truncations[-1])
    seeds = [m["seed"] for m in minari.load_dataset("dvrl_marl/surgeon-stop-v1").storage.get_episode_metadata([0, 1])]
    assert seeds == [0, 1]


def test_session_arguments_are_checked():
    from dvrl_marl.teleop.session import TeleopSession

    with pytest.raises(ValueError, match="seat"):
        TeleopSession(seat="camera", record=False)
    with pytest.raises(ValueError, match="frames_per_second"):
        TeleopSession(frames_per_second=0, record=False)
    with pytest.raises(ValueError, match="dataset id"):
        TeleopSession(dataset_id="no version")
    with pytest.raises(FileNotFoundError, match="no policy 'nobody'"):
        TeleopSession(partner="nobody", record=False)


# --- the web app, as a websocket client meets it ---------------------------------------------------------------------
websockets_client = pytest.importorskip("websockets.sync.client",
                                        reason='the web seat: pip install "dvrl-marl[teleop]"')
pytest.importorskip("starlette", reason='the web seat: pip install "dvrl-marl[teleop]"')


@pytest.fixture
def server(minari_store):
    from dvrl_marl.teleop.session import TeleopSession
    from dvrl_marl.teleop.web import TeleopServer

    server = TeleopServer(TeleopSession(partner="scripted", seed=5, silence_timeout=0.5,
                                        dataset_id="dvrl_marl/surgeon-web-v1"), port=0).start()
    yield server
    server.stop()


def ws_url(server, token=None):
    return f"ws://127.0.0.1:{server.port}/ws?token={server.token if token is None else token}"


def next_status(connection, timeout=10.0):
    from dvrl_marl.teleop.session import unpack_frame

    while True:
        message = connection.recv(timeout=timeout)
        if isinstance(message, bytes):
            status, jpeg = unpack_frame(message)
            assert jpeg[:2] == b"\xff\xd8", "each frame carries a JPEG"
            return status


def status_until(connection, predicate, timeout=20.0, ping=True):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        status = next_status(connection)
        if predicate(status):
            return status
        if ping:
            connection.send(json.dumps({"type": "ping"}))
    raise AssertionError(f"timed out; last status {status}")


def test_the_page_and_the_websocket_need_the_token(server):
    from websockets.exceptions import InvalidStatus

    page = urllib.request.urlopen(server.url, timeout=10).read().decode()
    assert "Start (Enter)" in page and "window.dvrl" in page  # the script is inline: nothing else to fetch
    status = json.loads(urllib.request.urlopen(server.url.replace("/?", "/status?"), timeout=10).read())
    assert status["seat"] == "grasper" and status["partner"] == "scripted"
    for url in (server.url.split("?")[0], server.url.replace(server.token, "x" * 22),
                server.url.split("?")[0] + "status"):
        with pytest.raises(urllib.error.HTTPError) as refused:
            urllib.request.urlopen(url, timeout=10)
        assert refused.value.code == 403
    for token in ("", "wrong-token-of-some-length"):
        with pytest.raises((InvalidStatus, Exception)) as error:
            with websockets_client.connect(ws_url(server, token)) as connection:
                connection.recv(timeout=5)
        assert "1008" in str(error.value) or "403" in str(error.value)


def test_the_server_refuses_other_interfaces_without_the_flag():
    from dvrl_marl.teleop.session import TeleopSession
    from dvrl_marl.teleop.web import TeleopServer, is_loopback

    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.4")
    session = TeleopSession(record=False)
    with pytest.raises(ValueError, match="allow_remote"):
        TeleopServer(session, host="0.0.0.0", port=0)
    with pytest.raises(ValueError, match="16 characters"):
        TeleopServer(session, port=0, token="short")
    session.close()


def test_a_page_opened_before_the_server_runs_waits_for_it_instead_of_being_refused():
    """The CLI prints the URL before serving: a person (or a script) opening it at once must get the page."""
    import threading

    from dvrl_marl.teleop.session import TeleopSession
    from dvrl_marl.teleop.web import TeleopServer

    server = TeleopServer(TeleopSession(record=False), port=0)
    pages = []
    opener = threading.Thread(target=lambda: pages.append(urllib.request.urlopen(server.url, timeout=30).read()))
    opener.start()
    time.sleep(0.5)  # the page's request is in before the server runs
    server.start()
    try:
        opener.join(30)
        assert pages and b"Start (Enter)" in pages[0]
    finally:
        server.stop()


def test_first_page_drives_a_second_watches_and_bad_messages_are_counted_not_fatal(server):
    with websockets_client.connect(ws_url(server)) as driver, websockets_client.connect(ws_url(server)) as watcher:
        assert json.loads(driver.recv(timeout=10)) == {"type": "role", "role": "controller"}
        assert json.loads(watcher.recv(timeout=10)) == {"type": "role", "role": "spectator"}
        status = status_until(watcher, lambda s: s["spectators"] == 1 and s["controller"], ping=False)
        assert status["state"] == "waiting"
        watcher.send(json.dumps({"type": "start"}))  # a spectator is not heard
        for _ in range(3):
            watcher.send(json.dumps({"type": "ping"}))  # its page's pings are no dropped input
        driver.send("not json")
        driver.send(b"\x00\x01")
        driver.send(json.dumps({"type": "ping", "pad": "x" * 5000}))
        driver.send(json.dumps({"type": "key", "code": "KeyD", "down": "maybe"}))
        driver.send("[" * 1500 + "]" * 1500)  # 3 kB of nesting: once it ended the driver's connection
        status = status_until(driver, lambda s: s["dropped_messages"] >= 6)
        assert status["dropped_messages"] == 6 and status["state"] == "waiting"
        assert "nested" in status["last_drop"]
        driver.send(json.dumps({"type": "start"}))
        driver.send(json.dumps({"type": "key", "code": "KeyW", "down": True, "seq": 3}))
        before = status_until(driver, lambda s: s["state"] == "running" and s["input_seq"] == 3)
        after = status_until(driver, lambda s: s["step"] >= before["step"] + 10)
        assert after["tip_mm"][1] > before["tip_mm"][1] and not after["teleop_lost"]
        watched = status_until(watcher, lambda s: s["step"] >= after["step"], ping=False)
        assert watched["tip_mm"][1] >= after["tip_mm"][1]  # the spectator sees the same episode
        try:  # over the websocket limit: that connection closes, the server stays up
            with websockets_client.connect(ws_url(server), max_size=None) as flooder:
                flooder.recv(timeout=10)
                flooder.send("x" * (2 << 20))
                for _ in range(100):
                    flooder.recv(timeout=10)
        except Exception:  # noqa: BLE001
            pass
        assert status_until(driver, lambda s: s["step"] > after["step"])["state"] == "running"


def test_a_silent_or_closed_page_holds_the_seat_and_a_new_page_takes_it_back(server):
    with websockets_client.connect(ws_url(server)) as driver:
        driver.recv(timeout=10)
        driver.send(json.dumps({"type": "start"}))
        driver.send(json.dumps({"type": "key", "code": "KeyD", "down": True}))
        status_until(driver, lambda s: s["state"] == "running" and not s["teleop_lost"])
        time.sleep(0.8)  # silent for longer than silence_timeout (0.5 s)
        silent = status_until(driver, lambda s: s["teleop_lost"], ping=False)
        held = status_until(driver, lambda s: s["step"] >= silent["step"] + 10, ping=False)
        assert held["tip_mm"] == silent["tip_mm"] and held["teleop_lost"]
        driver.send(json.dumps({"type": "ping"}))
        resumed = status_until(driver, lambda s: not s["teleop_lost"])
        moved = status_until(driver, lambda s: s["step"] >= resumed["step"] + 10)
        assert moved["tip_mm"][0] > resumed["tip_mm"][0]  # the key is still held: it moves again
    with websockets_client.connect(ws_url(server)) as watcher:  # the driver closed: the seat holds ...
        assert json.loads(watcher.recv(timeout=10))["role"] == "controller"  # ... until a new page takes it
        first = next_status(watcher)  # the newest frame when it joined: possibly from before the driver left
        status = status_until(watcher, lambda s: not s["teleop_lost"] and s["step"] >= first["step"] + 4)
        later = status_until(watcher, lambda s: s["step"] >= status["step"] + 10)
        assert later["tip_mm"] == status["tip_mm"]  # its keys start released


def test_a_session_has_a_status_before_its_first_episode(minari_store):
    from dvrl_marl.teleop.session import TeleopSession

    session = TeleopSession(record=False)
    assert session.status()["state"] == "starting" and session.observation is None
    session.close()
