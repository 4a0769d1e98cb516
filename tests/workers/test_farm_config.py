"""Farm settings and shot-root checks (no broker needed)."""

from __future__ import annotations

import os
from types import SimpleNamespace

import pytest

from workers.paths import PathRefused, check_job, check_under_roots
from workers.settings import FarmConfigError, load_settings


def _env(tmp_path, **kw):
    return {"TWEEN_FARM_CONFIG": os.devnull, "TWEEN_CACHE": str(tmp_path / "c"), **kw}


def test_embedded_default_needs_no_server(tmp_path):
    s = load_settings(_env(tmp_path))
    assert s.embedded
    assert s.broker_url.startswith("tweensqla+sqlite:///") and str(tmp_path / "c") in s.broker_url
    assert s.result_backend.startswith("db+sqlite:///")


def test_redis_settings_and_their_checks(tmp_path):
    s = load_settings(_env(tmp_path, TWEEN_BROKER_URL="redis://h:6379/2"))
    assert not s.embedded and s.result_backend == "redis://h:6379/2" and s.is_redis
    assert s.fill_time_limit < s.visibility_timeout
    with pytest.raises(FarmConfigError, match="visibility_timeout"):
        load_settings(_env(tmp_path, TWEEN_BROKER_URL="redis://h", TWEEN_VISIBILITY_TIMEOUT="30"))
    with pytest.raises(FarmConfigError, match="chords"):
        load_settings(_env(tmp_path, TWEEN_BROKER_URL="amqp://h"))
    with pytest.raises(FarmConfigError, match="rpc"):
        load_settings(_env(tmp_path, TWEEN_BROKER_URL="amqp://h", TWEEN_RESULT_BACKEND="rpc://"))
    with pytest.raises(FarmConfigError, match="integer"):
        load_settings(_env(tmp_path, TWEEN_BROKER_URL="redis://h", TWEEN_VISIBILITY_TIMEOUT="soon"))


def test_config_file(tmp_path):
    cfg = tmp_path / "farm.toml"
    cfg.write_text('broker_url = "redis://farm:6379/0"\nshot_roots = ["/shows"]\nvisibility_timeout = 90\n')
    s = load_settings({"TWEEN_FARM_CONFIG": str(cfg)})
    assert (
        s.broker_url == "redis://farm:6379/0" and s.shot_roots == ("/shows",) and s.visibility_timeout == 90
    )
    s = load_settings({"TWEEN_FARM_CONFIG": str(cfg), "TWEEN_VISIBILITY_TIMEOUT": "120"})
    assert s.visibility_timeout == 120  # the environment wins
    cfg.write_text('brokr_url = "x"\n')
    with pytest.raises(FarmConfigError, match="brokr_url"):
        load_settings({"TWEEN_FARM_CONFIG": str(cfg)})


def test_celery_app_is_configured_for_a_farm():
    from workers.app import app, train_app

    c = app.conf
    assert c.task_serializer == "json" and c.accept_content == ["json"] and c.result_serializer == "json"
    assert c.task_acks_late and c.task_reject_on_worker_lost and c.worker_prefetch_multiplier == 1
    assert c.task_soft_time_limit < c.task_time_limit
    assert not c.task_always_eager
    assert train_app.conf.task_time_limit > c.task_time_limit
    assert train_app.conf.task_default_queue != c.task_default_queue


def test_shot_roots(tmp_path):
    root = tmp_path / "show"
    (root / "seq").mkdir(parents=True)
    shot = root / "seq" / "sh010.usda"
    shot.write_text("#usda 1.0\n")
    assert check_under_roots(str(shot), [str(root)]) == os.path.realpath(shot)
    with pytest.raises(PathRefused, match="outside the shot roots"):
        check_under_roots(str(root / "seq" / ".." / ".." / "etc.usda"), [str(root)])
    with pytest.raises(PathRefused, match="outside"):
        check_under_roots(str(tmp_path / "show2" / "x.usda"), [str(root)])  # a prefix is not a parent
    (tmp_path / "secret.usda").write_text("")
    (root / "link.usda").symlink_to(tmp_path / "secret.usda")
    with pytest.raises(PathRefused):
        check_under_roots(str(root / "link.usda"), [str(root)])
    (root / "dirlink").symlink_to(tmp_path)
    with pytest.raises(PathRefused):
        check_job(str(shot), {"out_dir": str(root / "dirlink" / "out")}, [str(root)])
    with pytest.raises(PathRefused, match="no shot roots"):
        check_under_roots(str(shot), [])
    check_job(str(shot), {"out_dir": str(root / "out"), "mapping": None}, [str(root)])


def test_rig_training_has_its_own_app_queue_and_limits(tmp_path):
    import workers.rig_tasks  # noqa: F401  (what a worker imports through the app's include)
    import workers.train_tasks  # noqa: F401
    from workers.app import app, rig_app, train_app

    s = load_settings(_env(tmp_path, TWEEN_BROKER_URL="redis://h:6379/0"))
    assert s.train_rig_queue == "tween.train_rig" and s.train_rig_time_limit < s.train_rig_visibility_timeout
    with pytest.raises(FarmConfigError, match="train_rig_time_limit"):
        load_settings(_env(tmp_path, TWEEN_BROKER_URL="redis://h", TWEEN_TRAIN_RIG_TIME_LIMIT="90000",
                           TWEEN_TRAIN_RIG_VISIBILITY_TIMEOUT="3600"))  # fmt: skip
    with pytest.raises(FarmConfigError, match="three different queues"):
        load_settings(_env(tmp_path, TWEEN_TRAIN_RIG_QUEUE="tween.fill"))
    r, f = rig_app.conf, app.conf
    assert r.task_default_queue == r.tween.train_rig_queue != f.task_default_queue
    assert r.task_time_limit == r.tween.train_rig_time_limit and r.task_soft_time_limit < r.task_time_limit
    assert r.task_acks_late and r.accept_content == ["json"] and r.worker_prefetch_multiplier == 1
    assert rig_app.tasks["tween.train_rig"].app is rig_app
    assert train_app.conf.task_default_queue != r.task_default_queue
    # With Redis: its own key prefix (own unacked set) and visibility timeout of hours,
    # while the fill app keeps its minute.
    from celery import Celery

    from workers.app import configure

    rig = configure(Celery("r"), s, rig=True).conf.broker_transport_options
    fill = configure(Celery("f"), s).conf.broker_transport_options
    assert rig["global_keyprefix"] == "tween:rig:" and fill["global_keyprefix"] == "tween:"
    assert rig["visibility_timeout"] == s.train_rig_visibility_timeout > 3600 > fill["visibility_timeout"]


def test_train_rig_job_arguments_and_progress_meta():
    from pipeline.rig.progress import Progress
    from workers.errors import JobError
    from workers.rig_tasks import progress_meta, train_args

    args = train_args(
        "/s/clip.usda", "/m/x", {"schedule": "tiny", "seed": 3, "skeleton": "/W/Skel", "iters": None}
    )
    assert args == ["train-rig", "/s/clip.usda", "--out", "/m/x", "--skeleton", "/W/Skel", "--schedule", "tiny",
                    "--seed", "3"]  # fmt: skip
    with pytest.raises(JobError, match="unknown train-rig option"):
        train_args("/s/clip.usda", "/m/x", {"rm": "-rf"})
    rec = Progress("levels 3-4/5", 33, 60, {"d": 0.1}, 1.0, 2.0, stage_step=3, stage_steps=30,
                   group_levels=(3, 4), n_levels=5)  # fmt: skip
    meta = progress_meta(rec)
    assert (meta["levels"], meta["iteration"], meta["iterations"], meta["fraction"]) == ("3-4/5", 3, 30, 0.55)
    assert meta["loss"] == {"d": 0.1} and meta["step"] == 33


def test_train_rig_task_reports_progress_and_stops_the_trainer_at_the_soft_limit(tmp_path, monkeypatch):
    """The task body with a stand-in trainer: progress goes to the task meta; at the soft
    time limit (raised in the task as billiard does) the trainer's process group is stopped
    and the job fails with the resume hint."""
    import signal
    import sys

    from celery.exceptions import SoftTimeLimitExceeded

    import workers.rig_tasks as rt
    from workers.errors import JobError

    pidfile = tmp_path / "pid"
    script = (
        "import os, sys, time\n"
        "from pipeline.rig.progress import JsonLinesWriter, Progress\n"
        f"open({str(pidfile)!r}, 'w').write(str(os.getpid()))\n"
        "out = JsonLinesWriter(os.fdopen(int(sys.argv[1]), 'w'))\n"
        "for i in range(1, 31):\n"
        "    out(Progress('levels 1-2/4', i, 60, {}, 0.0, None, stage_step=i, stage_steps=30,\n"
        "                 group_levels=(1, 2), n_levels=4))\n"
        "    time.sleep(0.02)\n"
        "time.sleep(60)\n"
    )
    monkeypatch.setattr(
        rt, "command", lambda *a, progress_fd=None: [sys.executable, "-c", script, str(progress_fd)]
    )
    monkeypatch.setattr(rt, "check_paths", lambda *a: None)
    updates = []
    monkeypatch.setattr(rt.train_rig, "update_state", lambda state, meta: updates.append((state, meta)))

    def soft_limit(*_):
        raise SoftTimeLimitExceeded()

    old = signal.signal(signal.SIGALRM, soft_limit)
    signal.alarm(3)
    try:
        with pytest.raises(JobError) as ei:
            rt.train_rig.run(str(tmp_path / "clip.usda"), str(tmp_path / "m"), {"schedule": "tiny"})
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    assert "stopped at its time limit" in str(ei.value) and f"{tmp_path / '.m.partial'}/checkpoints" in str(
        ei.value
    )
    assert updates and all(s == "PROGRESS" for s, _ in updates)
    assert updates[-1][1]["iteration"] == 30 and updates[-1][1]["fraction"] == 0.5
    pid = int(pidfile.read_text())
    with pytest.raises(ProcessLookupError):
        os.kill(pid, 0)  # the trainer is gone


def test_state_reports_the_stage_that_failed_while_it_is_being_written(monkeypatch):
    """A failure is written to the failing stage, then to every later one; a poll that reads
    the early stage before that write and a later one after it must still name the cause."""
    from celery import states

    from workers import jobs
    from workers.app import SUBMITTED

    job = "job1"
    err = {"exc_message": "/x.usda: outside the shot roots"}
    reads = {f"{job}.validate": 0}
    # A stand-in backend: touching the real app's backend here would bind it to this test's
    # settings for the rest of the session (the farm tests configure their own broker).
    backend = SimpleNamespace(exception_to_python=lambda r: PathRefused(r["exc_message"]))
    monkeypatch.setattr(jobs, "app", SimpleNamespace(backend=backend))

    def meta(tid):
        if tid == job:
            return {"status": SUBMITTED, "result": {"shot": "/x.usda", "takes": 1}}
        if tid == f"{job}.validate":
            reads[tid] += 1  # the worker writes FAILURE here between the first and second read
            return {"status": states.STARTED if reads[tid] == 1 else states.FAILURE, "result": err}
        return {"status": states.FAILURE, "result": err}

    monkeypatch.setattr(jobs, "_meta", meta)
    js = jobs.state(job)
    assert js.state == "FAILURE" and js.stage == "validate" and "outside the shot roots" in js.error


@pytest.mark.parametrize(
    "bad",
    [
        {"TWEEN_FILL_TIME_LIMIT": "50s"},  # an integer setting that is not one
        {"config": 'brokr_url = "redis://h"\n'},  # a typo in the farm TOML
    ],
)
def test_a_bad_farm_setting_is_one_line_for_farm_commands_and_nothing_for_the_others(tmp_path, bad):
    import subprocess
    import sys

    from usd_fixtures import bandai_shot

    shot = bandai_shot(tmp_path / "sh.usda", frames=21)
    cfg = tmp_path / "farm.toml"
    cfg.write_text(bad.pop("config", ""))
    env = {**os.environ, **_env(tmp_path), "TWEEN_FARM_CONFIG": str(cfg), **bad}
    farm = [["status", "abc"], ["fill", shot], ["submit", shot], ["worker"],
            ["submit-library", tmp_path, "--out", tmp_path / "lib"]]  # fmt: skip
    for args in farm:
        r = subprocess.run([sys.executable, "-m", "pipeline.cli", *map(str, args)], env=env, capture_output=True,
                           text=True, timeout=120)  # fmt: skip
        assert r.returncode == 2, (args, r.stderr)
        assert r.stderr.count("\n") == 1 and r.stderr.startswith("tween: error:"), (args, r.stderr)
        assert "TWEEN_FILL_TIME_LIMIT" in r.stderr or "brokr_url" in r.stderr
    # Commands that need no farm are not broken by its configuration.
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "fill-local", str(shot), "--out-dir",
                        str(tmp_path / "out")], env=env, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize(
    "toml, env, says",
    [
        ('brokr_url = "redis://h"\n', {}, "unknown farm setting(s): brokr_url (did you mean broker_url?)"),
        ('fill_time_limit = "soon"\n', {}, "fill_time_limit: expected an integer, got 'soon'"),
        ("visibility_timeout = 1.5\n", {}, "visibility_timeout: expected an integer, got 1.5"),
        ("queue = 5\n", {}, "queue must be a string, not 5"),
        ('shot_roots = "/shows"\n', {}, "shot_roots must be a list of folder paths"),
        ("queue = [\n", {}, "cannot read farm config"),
        ("", {"TWEEN_FILL_TIME_LIMIT": "0"}, "TWEEN_FILL_TIME_LIMIT: must be 1 or more, got 0"),
        ("", {"TWEEN_RESTORE_INTERVAL": "-5"}, "TWEEN_RESTORE_INTERVAL: must be 1 or more, got -5"),
        ("", {"TWEEN_MAX_RETRIES": "x"}, "TWEEN_MAX_RETRIES: expected an integer, got 'x'"),
    ],
)
def test_every_configuration_mistake_is_named(tmp_path, toml, env, says):
    cfg = tmp_path / "farm.toml"
    cfg.write_text(toml)
    with pytest.raises(FarmConfigError) as e:
        load_settings({**_env(tmp_path), "TWEEN_FARM_CONFIG": str(cfg), **env})
    assert says in str(e.value) and "\n" not in str(e.value)
    if not env:
        assert str(cfg) in str(e.value)


def test_a_farm_config_named_but_missing_is_an_error_and_none_named_is_none(tmp_path):
    missing = tmp_path / "farm.toml"
    with pytest.raises(FarmConfigError, match=f"TWEEN_FARM_CONFIG={missing}: no such farm config file"):
        load_settings({"TWEEN_FARM_CONFIG": str(missing), "TWEEN_CACHE": str(tmp_path / "c")})
    assert load_settings({"TWEEN_FARM_CONFIG": os.devnull, "TWEEN_CACHE": str(tmp_path / "c")}).embedded
    assert load_settings(
        {"HOME": str(tmp_path), "TWEEN_CACHE": str(tmp_path / "c")}
    ).embedded  # the default path
    assert load_settings({**_env(tmp_path), "TWEEN_MAX_RETRIES": "0"}).max_retries == 0


def _refused(env: dict) -> str:
    """The one-line message of the farm configuration error ``env`` makes."""
    with pytest.raises(FarmConfigError) as e:
        load_settings(env)
    msg = str(e.value)
    assert "\n" not in msg, msg
    return msg


def test_a_queue_of_the_embedded_farm_is_refused(tmp_path):
    """A farm queue named like the embedded farm's private ones would make a second submit
    take its healthy jobs for a dead embedded client's and delete their files."""
    from workers.jobs import EMBEDDED_QUEUE_PREFIX
    from workers.settings import EMBEDDED_QUEUE_PREFIX as checked

    assert checked == EMBEDDED_QUEUE_PREFIX == "tween.embedded."
    msg = _refused(_env(tmp_path, TWEEN_QUEUE="tween.embedded.farm"))
    assert msg.startswith("TWEEN_QUEUE=tween.embedded.farm: queue names starting with tween.embedded."), msg
    cfg = tmp_path / "farm.toml"
    for key in ("queue", "train_queue", "train_rig_queue"):
        cfg.write_text(f'{key} = "tween.embedded.x"\n')
        assert _refused(_env(tmp_path, TWEEN_FARM_CONFIG=str(cfg))).startswith(f"{cfg}: {key}: queue names")
    assert load_settings(_env(tmp_path, TWEEN_QUEUE="tween.embeddedfarm")).queue == "tween.embeddedfarm"


@pytest.mark.parametrize(
    "toml, env, says",
    [
        ('queue = ""\n', {}, "{cfg}: queue: empty"),
        ('broker_url = ""\n', {}, "{cfg}: broker_url: empty"),
        ('result_backend = ""\nbroker_url = "amqp://h"\n', {}, "{cfg}: result_backend: empty"),
        ('key_prefix = "  "\n', {}, "{cfg}: key_prefix: empty"),
        ('security_digest = ""\n', {}, "{cfg}: security_digest: empty"),
        ('library = " "\n', {}, "{cfg}: library: empty"),
        ("", {"TWEEN_TRAIN_QUEUE": "  "}, "TWEEN_TRAIN_QUEUE='  ': empty"),
        ("", {"TWEEN_BROKER_URL": " "}, "TWEEN_BROKER_URL=' ': empty"),
    ],
)
def test_an_empty_string_setting_is_refused_naming_its_key(tmp_path, toml, env, says):
    cfg = tmp_path / "farm.toml"
    cfg.write_text(toml)
    msg = _refused({**_env(tmp_path), "TWEEN_FARM_CONFIG": str(cfg), **env})
    assert msg.startswith(says.format(cfg=cfg)) and "TWEEN_RESULT_BACKEND is required" not in msg, msg
    # An empty optional path is none, its default; an empty variable is not set.
    cfg.write_text('library = ""\ntls_ca_file = ""\n')
    s = load_settings({**_env(tmp_path), "TWEEN_FARM_CONFIG": str(cfg), "TWEEN_QUEUE": ""})
    assert s.library == "" and s.tls_ca_file == "" and s.queue == "tween.fill"


def test_a_farm_config_that_is_not_utf8_is_one_line_naming_it(tmp_path):
    cfg = tmp_path / "j.toml"
    cfg.write_bytes(b"\xff\xfe")
    msg = _refused(_env(tmp_path, TWEEN_FARM_CONFIG=str(cfg)))
    assert msg.startswith(f"{cfg}: cannot read farm config: not UTF-8 text"), msg


def test_a_farm_config_that_is_not_a_file_is_refused(tmp_path):
    folder = tmp_path / "conf"
    folder.mkdir()
    msg = _refused(_env(tmp_path, TWEEN_FARM_CONFIG=str(folder)))
    assert msg.startswith(f"TWEEN_FARM_CONFIG={folder}: a folder, not a farm config file"), msg
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    assert _refused(_env(tmp_path, TWEEN_FARM_CONFIG=str(fifo))).startswith(
        f"TWEEN_FARM_CONFIG={fifo}: not a regular"
    )
    # The default path: missing is no settings, a folder there is an error naming it.
    home = {"HOME": str(tmp_path), "TWEEN_CACHE": str(tmp_path / "c")}
    assert load_settings({**home, "TWEEN_FARM_CONFIG": ""}).embedded  # empty: the default path
    default = tmp_path / ".config" / "usd-tween" / "farm.toml"
    default.mkdir(parents=True)
    assert _refused(home).startswith(f"{default}: a folder"), _refused(home)
    assert load_settings({**home, "TWEEN_FARM_CONFIG": os.devnull}).embedded


def test_relative_paths_in_the_config_file_are_relative_to_its_folder(tmp_path, monkeypatch):
    conf = tmp_path / "conf"
    conf.mkdir()
    cfg = conf / "farm.toml"
    cfg.write_text('shot_roots = ["shows", "/abs/shows"]\nlibrary = "libs/studio"\n')
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    s = load_settings(_env(tmp_path, TWEEN_FARM_CONFIG="../conf/farm.toml"))
    assert s.shot_roots == (str(conf / "shows"), "/abs/shows"), s.shot_roots
    assert s.library == str(conf / "libs" / "studio")
    # The environment's stay relative to the working folder.
    s = load_settings(_env(tmp_path, TWEEN_FARM_CONFIG=str(cfg), TWEEN_LIBRARY="lib", TWEEN_SHOT_ROOTS="rel"))
    assert s.library == str(elsewhere / "lib") and s.shot_roots == ("rel",)


def test_limits_that_disagree_name_where_they_came_from(tmp_path):
    cfg = tmp_path / "farm.toml"
    cfg.write_text('broker_url = "redis://h"\nvisibility_timeout = 30\n')
    msg = _refused(_env(tmp_path, TWEEN_FARM_CONFIG=str(cfg)))
    assert msg.startswith(
        f"{cfg}: visibility_timeout: fill_time_limit (50 s) must be below visibility_timeout"
    ), msg
    msg = _refused(_env(tmp_path, TWEEN_FILL_SOFT_TIME_LIMIT="60"))
    assert msg.startswith("TWEEN_FILL_SOFT_TIME_LIMIT=60: fill_soft_time_limit (60 s) must be below"), msg
    msg = _refused(_env(tmp_path, TWEEN_BROKER_URL="redis://:pw@h", TWEEN_HEARTBEAT_INTERVAL="30"))
    assert msg.startswith("TWEEN_HEARTBEAT_INTERVAL=30: heartbeat_interval (30 s) must be at most a third"), (
        msg
    )
    cfg.write_text('train_queue = "tween.fill"\n')
    msg = _refused(_env(tmp_path, TWEEN_FARM_CONFIG=str(cfg)))
    assert msg.startswith(f"{cfg}: train_queue: queue, train_queue and train_rig_queue must be three"), msg
    msg = _refused(_env(tmp_path, TWEEN_BROKER_URL="amqp://u:pw@h//"))
    assert msg.startswith("TWEEN_BROKER_URL=amqp://u:***@h//: a non-Redis broker needs result_backend"), msg
    for garbage in ("garbage", "localhost:6379"):  # said "a non-Redis broker needs result_backend"
        msg = _refused(_env(tmp_path, TWEEN_BROKER_URL=garbage))
        assert msg.startswith(f"TWEEN_BROKER_URL={garbage}: not a broker URL (redis://"), msg


def test_seconds_settings_have_an_upper_bound(tmp_path):
    msg = _refused(_env(tmp_path, TWEEN_HEARTBEAT_INTERVAL="10000000000"))
    assert msg == "TWEEN_HEARTBEAT_INTERVAL: must be at most 604800 s (7 days), got 10000000000", msg
    cfg = tmp_path / "farm.toml"
    cfg.write_text("train_rig_visibility_timeout = 604801\n")
    assert _refused(_env(tmp_path, TWEEN_FARM_CONFIG=str(cfg))).startswith(
        f"{cfg}: train_rig_visibility_timeout: must be at most 604800 s"
    )
    assert "TWEEN_RENDER_FRAME_MS: must be at most 3600000 ms" in _refused(
        _env(tmp_path, TWEEN_RENDER_FRAME_MS="3600001")
    )
    assert (
        load_settings(_env(tmp_path, TWEEN_TRAIN_VISIBILITY_TIMEOUT="604800")).train_visibility_timeout
        == 604800
    )


@pytest.mark.parametrize(
    "toml, env",
    [
        ("", {"TWEEN_VISIBILITY_TIMEOUT": "1_000"}),
        ("", {"TWEEN_VISIBILITY_TIMEOUT": " 100 "}),
        ("", {"TWEEN_VISIBILITY_TIMEOUT": "+100"}),
        ("", {"TWEEN_VISIBILITY_TIMEOUT": "\u0661\u0660\u0660"}),  # Arabic-Indic digits
        ('visibility_timeout = "60"\n', {}),
        ("visibility_timeout = true\n", {}),
    ],
)
def test_an_integer_setting_must_be_an_integer(tmp_path, toml, env):
    cfg = tmp_path / "farm.toml"
    cfg.write_text(toml)
    msg = _refused({**_env(tmp_path), "TWEEN_FARM_CONFIG": str(cfg), **env})
    assert "visibility_timeout" in msg.lower() and "expected an integer" in msg, msg
    assert (str(cfg) in msg) == (not env), msg
