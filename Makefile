# make demo : install what is missing, then run the main job on the built-in default system
# make test : install what is missing (bpy and chromium included), then run the whole test suite
# make bench: every benchmark in its quick mode (python -m bench; each alone: python -m bench.NAME)
VENV   := .venv
PY     := $(VENV)/bin/python
OUT    ?= out/demo

.PHONY: demo test install install-test bench clean

install:
	@scripts/bootstrap.sh

install-test:
	@WITH_TEST_TOOLS=1 scripts/bootstrap.sh

demo: install
	@$(VENV)/bin/calib demo -o $(OUT)

test: install-test
	@$(PY) -m pytest -q

bench: install
	@$(PY) -m bench

clean:
	rm -rf out .pytest_cache
