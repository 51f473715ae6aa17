# The README's two commands: `make demo` (main job on the built-in mock rig) and
# `make test`. Both set up ./.venv first (scripts/setup.sh; cheap when up to date).
.PHONY: setup demo test bench clean

setup:
	@bash scripts/setup.sh

demo: setup
	.venv/bin/polycam demo --out demo-out

test: setup
	.venv/bin/python -m pytest -q

bench: setup
	@for b in benchmarks/bench_*.py; do echo "== $$b"; .venv/bin/python $$b || exit 1; done

# numba's on-disk caches (*.nbi / *.nbc in __pycache__) are keyed on each kernel's own
# source file only: after editing a module whose functions other kernels call or inline (e.g.
# polycam/derivatives.py, polycam/eq5.py), `make clean` so that they are recompiled.
clean:
	rm -rf demo-out .pytest_cache
	find . -path ./.venv -prune -o -name '*.nb[ic]' -print | xargs rm -f
