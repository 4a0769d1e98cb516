"""Farm settings and shot-root checks (no broker needed)."""

from __future__ import annotations

import os

import pytest

from workers.paths import PathRefused, check_job, check_under_roots
from workers.settings import FarmConfigError, load_settings


def _env(tmp_path, **kw):
    return {"TWEEN_FARM_CONFIG": str(tmp_path / "none.toml"), "TWEEN_CACHE": str(tmp_path / "c"), **kw}


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
