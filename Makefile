# oscar — the two set-up commands are `make demo` and `make test`. Both create the project's virtual environment
# (.venv/, gitignored) on first use and install into it; nothing is installed into the system's python3.
BASE_PYTHON ?= python3
VENV ?= .venv
PYTHON := $(VENV)/bin/python
PIP := $(PYTHON) -m pip
STAMP := $(VENV)/.oscar-installed
OUT ?= demo_out
# every extra the tests need (make test passes --strict-extras: a test skipped for a missing one fails)
EXTRAS := dev,mano,mesh,data,judge,text,tensorboard,ray,viz,policy,gym

.PHONY: install venv demo test test-fast test-install lint docs bench bench-gpu clean

install: $(STAMP)

venv: $(PYTHON)

$(PYTHON):
	@$(BASE_PYTHON) -c "import sys; sys.exit(0 if sys.version_info >= (3, 10) else 'oscar needs Python >= 3.10, found ' + sys.version.split()[0] + ' at ' + sys.executable)"
	$(BASE_PYTHON) -m venv $(VENV) || { rm -rf $(VENV); echo "error: '$(BASE_PYTHON) -m venv' failed; on Debian/Ubuntu install python3-venv" >&2; exit 2; }

# torch is pinned here (the CPU build installs from local disk in seconds); the package metadata accepts a range.
$(STAMP): $(PYTHON) pyproject.toml examples/oscar-toyarm/pyproject.toml requirements-ci.txt
	$(PIP) install -q -r requirements-ci.txt
	@# a metadata folder of a distribution named "oscar" in the checkout sits on sys.path when run from here and
	@# would register the built-in plugins a second time
	rm -rf oscar.egg-info
	$(PIP) install -q -e ".[$(EXTRAS)]" -e examples/oscar-toyarm
	@touch $(STAMP)

demo: install
	$(PYTHON) -m oscar_core.cli demo --out $(OUT)

# both test targets run on every core, one pytest-xdist worker per core (TEST_WORKERS=0: in this process); a worker
# takes a whole test file at a time (a module's fixtures are built once), the files that hold slow tests first
# (tests/conftest.py orders them; --no-loadscope-reorder keeps that order). Each worker's torch uses one thread unless
# OMP_NUM_THREADS says otherwise: a worker per core with torch's default of a thread per core would oversubscribe.
TEST_WORKERS ?= auto
XDIST := -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder
TEST_ENV := $(if $(filter 0,$(TEST_WORKERS)),,OMP_NUM_THREADS=$${OMP_NUM_THREADS:-1} )

test: install
	$(TEST_ENV)$(PYTHON) -m pytest -q --strict-extras $(XDIST)

# the tests not marked slow
test-fast: install
	$(TEST_ENV)$(PYTHON) -m pytest -q --strict-extras -m "not slow and not install" $(XDIST)

# a real install into a fresh virtual environment (downloads dependencies)
test-install: install
	$(PYTHON) -m pytest -q -m install

# ruff's format check and lint (settings in pyproject.toml) and the type check of the public API (mypy on tests/typing/public_api.py)
lint: install
	$(PYTHON) -m ruff format --check .
	$(PYTHON) -m ruff check .
	$(PYTHON) -m mypy

# docs/benchmarks.md from the measured JSON in benchmarks/measured/ (the record); a test fails while they disagree
docs: install
	$(PYTHON) benchmarks/make_docs.py

bench: install
	$(PYTHON) benchmarks/render.py
	$(PYTHON) benchmarks/rollout.py
	$(PYTHON) benchmarks/cli_rollout.py --model oscar-toy
	$(PYTHON) benchmarks/startup.py
	$(PYTHON) benchmarks/render_scale.py
	$(PYTHON) benchmarks/train.py
	$(PYTHON) benchmarks/distill_speed.py --student zoo/assets/oscar-toy-fast

# the GPU measurements (CUDA, random-weights 2B) run in the machine's own python3 (BASE_PYTHON) with its CUDA build
# of torch, not in .venv/ (whose torch is the pinned CPU build); oscar must be installed there. Each line is one job
# of a few minutes on an H100/H200-class GPU.
# measured on one H100: the eager table alone (--presets fast,paper --repeats 1) took about 100 s; the whole
# target takes well over 10 minutes, so each line writes its JSON as it goes (benchmarks/measured/ feeds
# docs/benchmarks.md through benchmarks/make_docs.py)
bench-gpu:
	$(BASE_PYTHON) benchmarks/rollout.py --gpu --compile --vae-variants --skip-tiny --repeats 3 \
		--json benchmarks/measured/rollout_gpu.json
	$(BASE_PYTHON) benchmarks/cli_rollout.py --size 2b --device cuda --compile-modes --repeats 1 \
		--json benchmarks/measured/cli_rollout_gpu.json
	$(BASE_PYTHON) benchmarks/train.py --step-table --step-size 2b --device cuda --step-repeats 3 \
		--json benchmarks/measured/train_step_gpu.json
	$(BASE_PYTHON) benchmarks/distill_speed.py --device cuda --dtype bfloat16 --student zoo/assets/oscar-toy-fast --json benchmarks/measured/distill_speed_gpu.json
	# the 2B closed-loop step (random weights, bf16): policy-visible latency per chunk and cells per GPU-hour for the
	# teacher (35 guided steps), --preset fast and a 4-step sampler without guidance, full VAE and tiny decoder
	for sampler in "teacher:" "fast:--preset fast" "4step:--steps 4 --no-guidance"; do \
		for decoder in "full:--full-decoder" "tiny:--tiny-decoder random"; do \
			$(BASE_PYTHON) benchmarks/closed_loop.py --size 2b --device cuda --sessions 2 --horizon 161 --batch 4 \
				--no-vae-probe $${sampler#*:} $${decoder#*:} \
				--json benchmarks/measured/closed_loop_2b_$${sampler%%:*}_$${decoder%%:*}_gpu.json || exit 1; \
		done; \
	done
	# the 4-step sampler with the tiny decoder and the tiny condition encoder (taew2_1's widths, random weights)
	$(BASE_PYTHON) benchmarks/closed_loop.py --size 2b --device cuda --sessions 2 --horizon 161 --batch 4 \
		--no-vae-probe --steps 4 --no-guidance --tiny-decoder random --tiny-encoder random \
		--json benchmarks/measured/closed_loop_2b_4step_tinyboth_gpu.json

clean:
	rm -rf .make $(OUT) golden-results benchmarks/results
