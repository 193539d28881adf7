"""The simulation's internal contracts: the production backend does not load the NumPy oracle."""

from __future__ import annotations

import json
import subprocess
import sys


def test_opencl_simulator_runs_without_the_numpy_oracle() -> None:
    """reference.py is the oracle the kernels are tested against, not a library: importing the
    OpenCL backend and the simulator, and stepping an OpenCL simulator with the default stages,
    must not load it. Checked in a fresh interpreter (this one has it loaded already)."""
    code = (
        "import json, sys\n"
        "import gazehdr.sim.opencl, gazehdr.sim.simulator\n"
        "from gazehdr.sim import Simulator\n"
        "Simulator(64, 48, backend='opencl').step(0.1)\n"
        "print(json.dumps(sorted(m for m in sys.modules if m.startswith('gazehdr.'))))\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    loaded = json.loads(run.stdout.splitlines()[-1])
    assert "gazehdr.sim.opencl" in loaded  # the check ran the OpenCL path
    assert "gazehdr.sim.reference" not in loaded
