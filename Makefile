# The README's two commands are `make run` and `make test`.
PY := .venv/bin/python

.PHONY: setup setup-test run test plugins ui clean

setup:
	bash scripts/setup.sh

setup-test:
	bash scripts/setup.sh test

run: setup
	$(PY) -m visphy_core $(ARGS)

# Test files run in parallel processes (pytest-xdist, one file per worker at a time so module
# fixtures are built once; the longest files first, tests/conftest.py). On 2 cores two workers
# took 479 s where one took 638 s (a 264-test subset); TEST_WORKERS=0 runs in this process.
TEST_WORKERS ?= 2
test: setup-test
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile $(PYTEST_ARGS)

plugins: setup
	$(PY) -m visphy_core plugins

# The MLflow UI of the runs under $(VISPHY_HOME) (default visphy-out); installs nothing.
ui:
	@test -x .venv/bin/mlflow || { echo "no .venv/bin/mlflow: run 'make run' first" >&2; exit 2; }
	.venv/bin/mlflow ui --backend-store-uri sqlite:///$(abspath $(or $(VISPHY_HOME),visphy-out))/mlflow.db

clean:
	rm -rf .venv visphy-out
