"""``jaxrl_robot.compilation``: where the persistent compilation cache lives, that a second process
finds what the first compiled, and what the CLI records of it."""

import json
import subprocess
import sys

from jaxrl_robot import compilation
from tests.subproc import ROOT, cpu_env
from train import cli, options
from train import ppo as ppo_cli


def test_resolve_cache_dir_takes_the_option_then_our_variable_then_jax_s_then_the_user_folder(monkeypatch, tmp_path):
    monkeypatch.delenv(compilation.CACHE_ENV, raising=False)
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert compilation.resolve_cache_dir(None) == str(tmp_path / "xdg" / "jaxrl-robot" / "xla")
    assert compilation.resolve_cache_dir("auto") == compilation.default_cache_dir()
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", "/somewhere/jax")
    assert compilation.resolve_cache_dir("auto") == "/somewhere/jax"
    monkeypatch.setenv(compilation.CACHE_ENV, str(tmp_path / "ours"))
    assert compilation.resolve_cache_dir("auto") == str(tmp_path / "ours")
    assert compilation.resolve_cache_dir(str(tmp_path / "flag")) == str(tmp_path / "flag")
    for off in ("off", "OFF", "none"):
        assert compilation.resolve_cache_dir(off) is None
    monkeypatch.setenv(compilation.CACHE_ENV, "off")
    assert compilation.resolve_cache_dir("auto") is None
    assert compilation.resolve_cache_dir(str(tmp_path / "flag")) == str(tmp_path / "flag")  # the flag wins


def test_an_unwritable_cache_folder_leaves_the_cache_off_with_one_line(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert compilation.enable_persistent_cache(str(blocker / "xla")) is None
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("warning: compile cache") and "--no-compile-cache" in err[0]


_PROGRAM = """
import json, sys
import jax, jax.numpy as jnp
from jaxrl_robot import compilation
log = compilation.compile_log()
compilation.enable_persistent_cache(sys.argv[1])
jax.block_until_ready(jax.jit(lambda x: jnp.sin(x) @ x.T)(jnp.ones((8, 8))))
print(json.dumps(log.since()))
"""


def test_a_second_process_takes_its_program_from_the_cache(tmp_path):
    """Two processes compile the same program into one cache folder: the first misses and writes it,
    the second finds it (the counts come from JAX's own monitoring events)."""
    env = cpu_env()
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    env["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"  # the program is small: cache it however fast
    runs = []
    for _ in range(2):
        out = subprocess.run([sys.executable, "-c", _PROGRAM, str(tmp_path / "cache")], cwd=ROOT, env=env,
                             capture_output=True, text=True, timeout=300)  # fmt: skip
        assert out.returncode == 0, out.stderr[-2000:]
        runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
    first, second = runs
    assert first["cache_dir"] == second["cache_dir"] == str(tmp_path / "cache")
    assert first["programs"] >= 1 and first["cache_misses"] == first["cache_requests"] >= 1
    assert first["cache_hits"] == 0
    assert second["cache_requests"] == first["cache_requests"]
    assert second["cache_hits"] == second["cache_requests"] and second["cache_misses"] == 0


def test_compile_log_counts_a_new_program_and_names_it():
    import jax
    import jax.numpy as jnp

    x = jax.block_until_ready(jnp.arange(5))
    log = compilation.compile_log()
    mark = log.mark()

    def twice_plus_seven(x):
        return 2 * x + 7

    jax.block_until_ready(jax.jit(twice_plus_seven)(x))
    got = log.since(mark)
    assert got["programs"] == 1
    assert got["compile_s"] >= 0 and got["trace_s"] >= 0
    assert [s["name"] for s in got["slowest"]] == ["jit(twice_plus_seven)"]


def test_no_compile_cache_is_the_off_spelling_and_the_cache_option_is_not_saved():
    assert cli.cache_flags(["--env", "arm7", "--no-compile-cache"]) == ["--env", "arm7", "--compile-cache", "off"]
    args = ppo_cli.CLI.parse(["--env", "brax:fast", "--no-compile-cache"])
    assert args.compile_cache == "off"
    assert "compile_cache" in options.COMMAND_LINE_FIELDS  # a resumed run takes it from its command line
    _, _, config = ppo_cli.CLI.build(args)
    assert "compile_cache" not in config["args"]


# ---- ProgramCache: whole programs kept between processes ---------------------------------------------------
def _program(traced):
    """``f(params, x) -> ({"y": …}, count)``; appends to ``traced`` each time it is traced."""
    import jax.numpy as jnp

    def f(params, x):
        traced.append(1)
        return {"y": jnp.tanh(x @ params["w"]) + params["b"]}, jnp.sum(x > 0)

    return f


def _args(rows=3):
    import numpy as np

    rng = np.random.default_rng(0)
    params = {"w": rng.normal(size=(4, 2)).astype("float32"), "b": np.float32(0.5)}
    return params, rng.normal(size=(rows, 4)).astype("float32")


def test_a_kept_program_is_found_by_a_new_cache_without_tracing_and_computes_the_same(tmp_path):
    import jax
    import numpy as np

    traced = []
    f, args = _program(traced), _args()
    expected = jax.jit(f)(*args)
    assert len(traced) == 1
    log = compilation.compile_log()
    mark = log.mark()
    first = compilation.ProgramCache(str(tmp_path), {"run": 1}).compile("f", f, *args)(*args)
    assert len(traced) == 2 and len(list(tmp_path.glob("f-*.jaxexport"))) == 1
    again = compilation.ProgramCache(str(tmp_path), {"run": 1})  # as a later process would build it
    second = again.compile("f", f, *args)(*args)
    assert len(traced) == 2  # loaded, not traced
    for got in (first, second):
        assert jax.tree.structure(got) == jax.tree.structure(expected)
        for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(expected), strict=True):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert log.since(mark)["program_cache"] == {"loaded": 1, "built": 1, "load_s": log.since(mark)["program_cache"]
                                                ["load_s"], "unsaved": 0}  # fmt: skip
    compilation.ProgramCache(str(tmp_path), {"run": 2}).compile("f", f, *args)  # other settings: another program
    compilation.ProgramCache(str(tmp_path), {"run": 1}).compile("f", f, *_args(rows=5))  # other shapes: another
    assert len(traced) == 4 and len(list(tmp_path.glob("f-*.jaxexport"))) == 3


def test_a_damaged_kept_program_is_built_again_with_one_note(tmp_path, capsys):
    import numpy as np

    traced = []
    f, args = _program(traced), _args()
    cache = compilation.ProgramCache(str(tmp_path), {"run": 1})
    expected = cache.compile("f", f, *args)(*args)
    (path,) = tmp_path.glob("f-*.jaxexport")
    path.write_bytes(path.read_bytes()[:100])
    got = compilation.ProgramCache(str(tmp_path), {"run": 1}).compile("f", f, *args)(*args)
    assert len(traced) == 2
    np.testing.assert_array_equal(np.asarray(got[0]["y"]), np.asarray(expected[0]["y"]))
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("note: kept program f-") and "building it again" in err[0]
    compilation.ProgramCache(str(tmp_path), {"run": 1}).compile("f", f, *args)
    assert len(traced) == 2  # the rebuilt program was kept


def test_a_program_that_cannot_be_kept_still_runs(tmp_path, capsys):
    import jax
    import numpy as np

    def with_callback(x):
        return jax.pure_callback(lambda v: np.asarray(v) * 2, jax.ShapeDtypeStruct(x.shape, x.dtype), x) + 1

    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    log = compilation.compile_log()
    mark = log.mark()
    x = np.arange(3, dtype="float32")
    got = compilation.ProgramCache(str(tmp_path), {}).compile("cb", with_callback, x)(x)  # not exportable
    np.testing.assert_array_equal(np.asarray(got), [1, 3, 5])
    got = compilation.ProgramCache(str(blocker / "programs"), {}).compile("f", _program([]), *_args())(*_args())
    assert got[0]["y"].shape == (3, 2)  # a folder that cannot be written: built, not kept
    assert log.since(mark)["program_cache"]["unsaved"] == 2 and not list(tmp_path.glob("*.jaxexport"))
    assert all(line.startswith("note: ") for line in capsys.readouterr().err.strip().splitlines())


def test_the_key_follows_the_project_files(tmp_path):
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "a.py").write_text("x = 1\n")
    before = compilation._files_digest(str(tmp_path / "pkg"))
    (tmp_path / "pkg" / "a.py").write_text("x = 2\n")
    assert compilation._files_digest(str(tmp_path / "pkg")) != before
    assert cli.program_context({"args": {"seed": 3, "out": "x", "env": "arm7"}, "ppo": {"gamma": 0.9}}) == {
        "args": {"env": "arm7"}, "ppo": {"gamma": 0.9}}  # other seeds and folders share programs


def test_the_key_follows_the_lane_map_variable(tmp_path, monkeypatch):
    """A program kept under one ``JAXRL_LANE_MAP`` is not the one a run under another loads (same run, same files)."""
    from jaxrl_robot import parallel
    from jaxrl_robot.compilation import programs

    keys = []
    try:
        for value in ("", "vmap", "shard_map"):
            monkeypatch.setenv(parallel.IMPL_ENV, value)
            programs._process_context.cache_clear()
            keys.append(programs.ProgramCache(str(tmp_path), {"ppo": {"gamma": 0.9}})._context)
    finally:
        monkeypatch.undo()
        programs._process_context.cache_clear()
    assert len(set(keys)) == 3


def test_a_program_compiled_ahead_is_the_one_a_matching_call_runs(tmp_path):
    """``CachedJit.compile_ahead`` builds the program in a thread from shapes alone; the call with arguments of
    that signature runs it (traced once in all), equal to ``jax.jit``; other arguments compile in line."""
    import jax
    import numpy as np

    traced = []
    f, args = _program(traced), _args()
    expected = jax.jit(f)(*args)
    jitted = compilation.ProgramCache(str(tmp_path), {"run": 1}).jit("f", f)
    sharding = jax.device_put(np.zeros(())).sharding
    described = jax.tree.map(lambda x: jax.ShapeDtypeStruct(np.shape(x), x.dtype, sharding=sharding), args)
    future = jitted.compile_ahead(*described)
    future.result(timeout=120)
    assert len(traced) == 2  # jax.jit's and the one ahead
    placed = jax.device_put(args)  # committed arrays: the shardings the description named
    for a, b in zip(jax.tree.leaves(jitted(*placed)), jax.tree.leaves(expected), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert len(traced) == 2  # the call waited for the program ahead instead of tracing again
    other = _args(rows=5)
    np.testing.assert_allclose(np.asarray(jitted(*other)[0]["y"]), np.asarray(jax.jit(f)(*other)[0]["y"]), atol=1e-6)
    assert len(traced) == 4  # a signature nobody described: traced for the cache (and once by the oracle)


def test_seed_program_compiles_the_chunk_ahead_only_while_the_programs_are_not_kept(tmp_path):
    """``SeedProgram.compile_ahead`` starts the chunk's build before ``init`` on a first run (the chunk traced
    once, from the described state), not on a run whose programs are kept; the states are ``jax.jit``'s."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxrl_robot.types import Trainer
    from train.seeds import SeedProgram

    traced = []

    def init(key):
        return {"w": jax.random.normal(key, (3,)), "t": jnp.zeros((), jnp.int32)}

    def update(state):
        traced.append(1)
        return {"w": state["w"] * 0.5 + 1.0, "t": state["t"] + 1}, {"norm": jnp.linalg.norm(state["w"])}

    trainer = Trainer(init=init, update=update, policy=None, num_updates=2, env_steps_per_update=1)
    oracle = SeedProgram.of(trainer, 1)
    want = oracle.update(oracle.init([7]))
    for seeds, started in ((([7]), True), (([7]), False)):  # the second: as a later process, programs kept
        traced.clear()
        program = SeedProgram.of(trainer, 1, cache=compilation.ProgramCache(str(tmp_path), {"run": 1}))
        assert program.compile_ahead(seeds) is started
        got = program.update(program.init(seeds))
        assert len(traced) == (1 if started else 0)
        for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want), strict=True):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert SeedProgram.of(trainer, 1).compile_ahead([7]) is False  # no program cache: jax.jit's own
    for seed_map in ("vmap", "loop"):  # several seeds: one program over a seed axis, or one looped over them
        oracle = SeedProgram.of(trainer, 2, seed_map)
        want = oracle.update(oracle.init([7, 8]))
        traced.clear()
        program = SeedProgram.of(trainer, 2, seed_map, compilation.ProgramCache(str(tmp_path / seed_map), {"run": 1}))
        assert program.compile_ahead([7, 8]) is True
        got = program.update(program.init([7, 8]))
        assert len(traced) == 1  # built ahead, from the described state, and used by the call
        for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want), strict=True):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


_LANES_PROGRAM = """
import sys
import jax, numpy as np
from jaxrl_robot import compilation, parallel
assert len(jax.devices()) == 2
mesh = parallel.lane_mesh(2)

def init(key):  # as a trainer's init: a key in, lanes split over the mesh out
    return jax.lax.with_sharding_constraint(jax.random.normal(key, (8, 3)), parallel.lane_sharding(mesh))

key = jax.random.PRNGKey(3)  # uncommitted, as the runs make their keys
expected = np.asarray(jax.jit(init)(key))
log = compilation.compile_log()
for run in ("built", "loaded"):
    mark = log.mark()
    out = compilation.ProgramCache(sys.argv[1], {"run": 1}).compile("init", init, key)(key)
    assert len(out.sharding.device_set) == 2
    np.testing.assert_array_equal(np.asarray(out), expected)
    assert log.since(mark)["program_cache"][run] == 1, log.since(mark)
print("OK")
"""


def test_a_program_over_two_devices_made_from_an_uncommitted_key_is_kept_and_loaded(tmp_path):
    """A key made with ``jax.random.PRNGKey`` sits on the default device without being committed there: the kept
    program leaves its placement open and calls it replicated over the program's devices, as ``jax.jit`` does
    (it used to be left unkept on several devices, with a note, and compiled again by every run)."""
    out = subprocess.run([sys.executable, "-c", _LANES_PROGRAM, str(tmp_path)], cwd=ROOT, env=cpu_env(devices=2),
                         capture_output=True, text=True, timeout=300)  # fmt: skip
    assert out.returncode == 0 and "OK" in out.stdout, out.stdout[-2000:] + out.stderr[-3000:]
    assert "not kept" not in out.stdout + out.stderr
    assert len(list(tmp_path.glob("init-*.jaxexport"))) == 1
