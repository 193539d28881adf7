"""The child process of one fuzz target: `python -m gazehdr.fuzz.worker TARGET [libFuzzer args]`.

It imports the target under atheris' instrumentation and hands control to libFuzzer, which
runs the corpus first, then mutants; on a crash (an exception other than the documented
errors, a deadly signal from C++ code, a time-out or an out-of-memory) libFuzzer writes the
input to its `-artifact_prefix` and exits non-zero. The parent (`gazehdr.fuzz.runner`) reads
what it printed.
"""

from __future__ import annotations

import contextlib
import sys


def main(argv: list[str]) -> None:
    import atheris

    from gazehdr.fuzz.jsonmut import json_mutator, jsonl_mutator
    from gazehdr.fuzz.targets import TARGETS

    target = TARGETS[argv[1]]
    with atheris.instrument_imports(include=list(target.instrument)):
        one, documented = target.load()

    def test_one_input(data: bytes) -> None:
        with contextlib.suppress(documented):
            one(data)

    mutators = {"json": json_mutator, "jsonl": jsonl_mutator}
    extra = {}
    if target.mutator:
        # atheris.Mutate is bound by Fuzz(): look it up at each call, not now.
        extra["custom_mutator"] = mutators[target.mutator](lambda d, n: atheris.Mutate(d, n))
    atheris.Setup([argv[0], *argv[2:]], test_one_input, **extra)
    atheris.Fuzz()


if __name__ == "__main__":
    main(sys.argv)
