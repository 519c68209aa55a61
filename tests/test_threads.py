"""Thread counts are held to the machine's cores with a warning wherever they are read, and
a training config's counts must be finite whole numbers (NaN once trained nothing, exit 0)."""

import json
import warnings

import numpy as np
import pytest

from archhead_addon.io.errors import InputError, InputWarning
from archhead_addon.splat.kernel import RasterSettings
from archhead_addon.threads import (
    _openblas_thread_functions,
    choose_openmp_waiting,
    limit_thread_environment,
    machine_cores,
    one_blas_thread,
    thread_count,
)
from archhead_addon.train.__main__ import main
from archhead_addon.train.config import TrainConfig, config_data

CORES = machine_cores()
HUGE = 1_000_000


def test_thread_counts_are_clamped_with_a_warning_naming_where():
    with pytest.warns(
        InputWarning, match=rf"my.json: key 'threads': {HUGE} threads.*using {CORES}"
    ):
        assert thread_count(HUGE, "my.json", "threads") == CORES
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning for counts that fit
        assert thread_count(1) == 1
        assert thread_count(0) == thread_count(-3) >= 1  # the default
        assert thread_count(np.int64(CORES)) == thread_count(float(CORES)) == CORES
    for bad in (1.5, float("nan"), float("inf"), "4", True, None):
        with pytest.raises(InputError, match="key 'num_threads': a thread count must be"):
            thread_count(bad, "f", "num_threads")


def test_the_kernel_and_the_environment_are_held_to_the_cores(monkeypatch):
    K = np.array([[10.0, 0, 4], [0, 10.0, 4], [0, 0, 1]])
    with pytest.warns(InputWarning, match="key 'num_threads'"):
        assert RasterSettings(np.eye(4), K, 8, 8, num_threads=HUGE).to_c().num_threads == CORES
    monkeypatch.setenv("OMP_NUM_THREADS", str(HUGE))
    assert RasterSettings(np.eye(4), K, 8, 8).to_c().num_threads == CORES  # 0: the default
    env = {"OMP_NUM_THREADS": f"{HUGE},2", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "x"}
    with pytest.warns(InputWarning, match="environment: key 'OMP_NUM_THREADS'"):
        limit_thread_environment(env)
    assert env == {
        "OMP_NUM_THREADS": str(CORES),
        "OPENBLAS_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "x",
    }


def test_numpys_openblas_is_held_to_one_thread_and_given_its_count_back():
    functions = _openblas_thread_functions()
    if functions is None:  # another BLAS: the block changes nothing and says so
        with one_blas_thread() as held:
            assert not held
        return
    get, _ = functions
    before = get()
    with one_blas_thread() as held:
        assert held and get() == 1
        assert float(np.ones((64, 64), np.float32) @ np.ones(64, np.float32) @ np.ones(64)) > 0
        with one_blas_thread() as inner:  # a decode inside a decode (culling's reach) nests
            assert inner and get() == 1
        assert get() == 1
    assert get() == before


def test_training_config_counts(tmp_path):
    path = tmp_path / "c.json"
    path.write_text(json.dumps({"threads": HUGE, "stage1_steps": 1e3}))
    with pytest.warns(InputWarning, match=rf"c.json: key 'threads'.*using {CORES}"):
        config = TrainConfig.load(path)
    assert config.threads == CORES and config.stage1_steps == 1000
    for text, key in (
        ('{"stage1_steps": NaN}', "stage1_steps"),
        ('{"stage2_steps": Infinity}', "stage2_steps"),
        ('{"stage1_steps": -5}', "stage1_steps"),
        ('{"stage1_steps": 0, "stage2_steps": 0}', "stage1_steps"),
        ('{"checkpoint_every": 0}', "checkpoint_every"),
        ('{"stage2_steps": 2.5}', "stage2_steps"),
        ('{"lods_per_step": "3"}', "lods_per_step"),
        ('{"threads": -1}', "threads"),
        ('{"lr": {"features": NaN}}', "lr.features"),
        ('{"lr_final_ratio": NaN}', "lr_final_ratio"),
    ):
        path.write_text(text)
        for read in (TrainConfig.load, config_data):
            with pytest.raises(InputError, match=rf"^{path}: key '{key}': ") as caught:
                read(path)
            assert (caught.value.path, caught.value.key) == (path, key)


def test_a_nan_step_count_exits_2_before_training(tmp_path, capsys):
    config = tmp_path / "nan.json"
    config.write_text('{"stage1_steps": NaN}')
    out = tmp_path / "run"
    rc = main(["--data", str(tmp_path / "none"), "--out", str(out), "--config", str(config)])
    assert rc == 2
    assert f"error: {config}: key 'stage1_steps': must be a finite whole number" in (
        capsys.readouterr().err
    )
    assert not out.exists()


def test_openmp_threads_spin_briefly_on_quiet_cores_and_sleep_on_busy_ones(monkeypatch):
    import archhead_addon.threads as threads

    monkeypatch.setattr(threads.os, "getloadavg", lambda: (0.2, 1.0, 1.0))
    quiet = {}
    assert "spin" in choose_openmp_waiting(quiet)
    assert quiet == {"GOMP_SPINCOUNT": str(threads.SPIN_COUNT)}

    monkeypatch.setattr(threads.os, "getloadavg", lambda: (3.0, 1.0, 1.0))
    busy = {}
    assert "sleep" in choose_openmp_waiting(busy)
    assert busy == {"OMP_WAIT_POLICY": "PASSIVE"}

    for chosen in ({"OMP_WAIT_POLICY": "ACTIVE"}, {"GOMP_SPINCOUNT": "0"}):
        environ = dict(chosen)
        assert "as set" in choose_openmp_waiting(environ)
        assert environ == chosen  # the user's choice stands


def test_a_child_gets_the_waiting_chosen_for_it_and_this_process_keeps_its_own(
    monkeypatch, tmp_path
):
    """Avatar from Video chooses once, before the tracker loads the cores, and gives the
    choice to both stages' processes (BackendRun's env), leaving Blender's environment alone."""
    import os
    import sys

    import archhead_addon.threads as threads
    from archhead_addon.backend_process import BackendRun

    for name in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(threads.os, "getloadavg", lambda: (0.2, 1.0, 1.0))
    chosen = threads.openmp_waiting_env()
    assert chosen == {"GOMP_SPINCOUNT": str(threads.SPIN_COUNT)}
    assert "GOMP_SPINCOUNT" not in os.environ
    show = "import os, sys; sys.stderr.write('spin=' + os.environ.get('GOMP_SPINCOUNT', 'none'))"
    run = BackendRun([sys.executable, "-c", show], tmp_path / "child.log", env=chosen)
    assert run.process.wait(60) == 0
    run.close()
    assert f"spin={threads.SPIN_COUNT}" in (tmp_path / "child.log").read_text()
