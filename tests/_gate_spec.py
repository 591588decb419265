"""The sweeps of the cornea's path the tests write: :func:`cornea_spec` (shared by the gate, plugin,
CLI and sweep tests), and :data:`SPEC`, the small sweep the gate tests run (anm_pod 4/6 and
pod_interp 4 modes), shared by test_check.py and test_check_ab.py."""
from __future__ import annotations

#: the evaluations the tests give the cornea's case
PATH = '{ kind = "path" }'
BEYOND = '{ kind = "path", beyond = [2.0] }'
HELD_OUT = '{ kind = "path", held_out = true }'


def cornea_spec(name: str, methods, *, latency_steps: int = 20, warmup: int = 2, evaluation: str | None = None,
                sweep: str = "") -> str:
    """The TOML of a sweep ``name`` of one case, ``cornea_pinch`` trained on every second state of its
    path (``evaluation``: the case's evaluation as an inline table, none by default), timed over
    ``latency_steps`` steps after ``warmup``, one reference sample; ``sweep``: more lines of the
    ``[sweep]`` table. ``methods``: the ``[[method]]`` tables in order, each a name or ``(name,
    lines)`` whose TOML lines follow the name.

    One key a line, as the tests edit them (``str.replace`` of ``latency_steps = 5``, ``warmup = 1``,
    ``every = 2``, ``evaluation = { kind = "path" }``), and the text ends in the last method's table,
    so that a test may append keys to it."""
    tables = ""
    for method in methods:
        method, lines = (method, "") if isinstance(method, str) else method
        tables += f'[[method]]\nname = "{method}"\n' + (f"{lines.strip()}\n" if lines else "")
    return (f'\n[sweep]\nname = "{name}"\n' + (f"{sweep.strip()}\n" if sweep else "")
            + f"[protocol]\nlatency_steps = {latency_steps}\nwarmup = {warmup}\nreference_samples = 1\n"
            + '[[case]]\nname = "cornea_pinch"\ntraining = { kind = "path", every = 2 }\n'
            + (f"evaluation = {evaluation}\n" if evaluation else "") + tables)


SPEC = cornea_spec(
    "gate", [("anm_pod", 'options = { eps = 1e-6, max_segments = 1 }\nlist = [{ n_modes = 4, order = 6 }]'),
             ("pod_interp", "grid = { n_modes = [4] }")],
    latency_steps=200, warmup=20, evaluation=BEYOND,
    # the tests edit this column of the stored rows to move an error (the default is claimed_error)
    sweep='error_metric = "max_rel_l2"')
