# oscar — the two set-up commands are `make demo` and `make test`.
PYTHON ?= python3
PIP := $(PYTHON) -m pip
STAMP := .make/installed
OUT ?= demo_out

.PHONY: install demo test test-fast test-install bench bench-gpu clean

install: $(STAMP)

# torch is pinned here (the CPU build installs from local disk in seconds);
# the package metadata accepts a range.
$(STAMP): pyproject.toml examples/oscar-toyarm/pyproject.toml requirements-ci.txt
	$(PIP) install -r requirements-ci.txt
	@# the distribution was called "oscar" before it became "oscar-wm": remove that old install (only if it is ours)
	@# and the metadata folder its editable install left in the checkout (found on sys.path when run from here)
	rm -rf oscar.egg-info
	@$(PYTHON) -c "import importlib.metadata as m, sys; sys.exit('Skeleton-conditioned' not in (m.metadata('oscar')['Summary'] or ''))" 2>/dev/null && $(PIP) uninstall -y -q oscar || true
	$(PIP) install -e ".[dev,mano,mesh,data,judge,text,tensorboard,ray]" -e examples/oscar-toyarm
	@mkdir -p .make && touch $(STAMP)

demo: install
	$(PYTHON) -m oscar_core.cli demo --out $(OUT)

test: install
	$(PYTHON) -m pytest -q

test-fast: install
	$(PYTHON) -m pytest -q -m "not slow and not install"

# a real install into a fresh virtual environment (downloads dependencies)
test-install: install
	$(PYTHON) -m pytest -q -m install

bench: install
	$(PYTHON) benchmarks/render.py
	$(PYTHON) benchmarks/rollout.py
	$(PYTHON) benchmarks/cli_rollout.py --model oscar-toy
	$(PYTHON) benchmarks/render_scale.py
	$(PYTHON) benchmarks/train.py

# the GPU measurements (CUDA, random-weights 2B; no `install` prerequisite: it would put the pinned CPU torch in
# place of this machine's CUDA build). Each line is one job of a few minutes on an H100/H200-class GPU.
bench-gpu:
	$(PYTHON) benchmarks/rollout.py --gpu --compile --vae-variants --skip-tiny --repeats 3 \
		--json benchmarks/results/rollout_gpu.json
	$(PYTHON) benchmarks/cli_rollout.py --size 2b --device cuda --compile-modes --repeats 1 \
		--json benchmarks/results/cli_rollout_gpu.json
	$(PYTHON) benchmarks/train.py --step-table --step-size 2b --device cuda --step-repeats 3 \
		--json benchmarks/results/train_step_gpu.json

clean:
	rm -rf .make $(OUT) golden-results benchmarks/results
