"""The small sweep the gate tests run (cornea path: anm_pod 4/6 and pod_interp 4 modes),
shared by test_check.py and test_check_ab.py."""

SPEC = """
[sweep]
name = "gate"
# the tests edit this column of the stored rows to move an error (the default is claimed_error)
error_metric = "max_rel_l2"
[protocol]
latency_steps = 200
warmup = 20
reference_samples = 1
[[case]]
name = "cornea_pinch"
training = { kind = "path", every = 2 }
evaluation = { kind = "path", beyond = [2.0] }
[[method]]
name = "anm_pod"
options = { eps = 1e-6, max_segments = 1 }
list = [{ n_modes = 4, order = 6 }]
[[method]]
name = "pod_interp"
grid = { n_modes = [4] }
"""
