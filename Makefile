# Every target sets itself up from a machine that has only python3.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
# The tests run in two processes where there are two cores (pytest-xdist), a module's tests
# in one of them, so a module's fixture is set up once.
PYTEST_ARGS ?= -n auto --maxprocesses 2 --dist loadscope

.PHONY: setup demo test browser bench bench-peers stress fuzz clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[robot,host,test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/btf-host demo --out demo-out

# The tests start hundreds of Python processes (robots, stations, commands): each reads its
# modules' cached bytecode, even where the environment turns the caching off.
test: $(STAMP) browser
	env -u PYTHONDONTWRITEBYTECODE $(BIN)/python -m pytest -q $(PYTEST_ARGS)

# The operator page's tests drive a real browser: Debian's chromium (root or sudo installs it).
browser:
	command -v chromium >/dev/null || { $$(command -v sudo) apt-get update -qq && \
	  $$(command -v sudo) apt-get install -y -qq --no-install-recommends chromium; }

bench: $(STAMP)
	$(BIN)/python -m benchmarks

# The accuracy peer of `python -m benchmarks photos`: R SuppDists from Debian (needs root or sudo).
bench-peers:
	command -v Rscript >/dev/null && Rscript -e 'library(SuppDists)' >/dev/null 2>&1 || \
	  { $$(command -v sudo) apt-get update -qq && $$(command -v sudo) apt-get install -y -qq --no-install-recommends r-base-core r-cran-suppdists; }

stress: $(STAMP)
	BTF_STRESS=1 $(BIN)/python -m pytest -q -m slow --hypothesis-profile=stress tests

# Coverage-guided fuzzing of the radio decoders with atheris (libFuzzer); FUZZ_RUNS inputs.
FUZZ_RUNS ?= 500000
fuzz: $(STAMP)
	$(BIN)/python -m pip install --quiet 'atheris>=2.3'
	$(BIN)/python tests/radio/fuzz_radio.py --seeds .fuzz-corpus
	$(BIN)/python tests/radio/fuzz_radio.py .fuzz-corpus -atheris_runs=$(FUZZ_RUNS)

clean:
	rm -rf $(VENV) demo-out .pytest_cache .hypothesis .fuzz-corpus
