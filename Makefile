# The README's two commands are `make run` and `make test`.
PY := .venv/bin/python

.PHONY: setup setup-test run test plugins ui clean

setup:
	bash scripts/setup.sh

setup-test:
	bash scripts/setup.sh test

run: setup
	$(PY) -m visphy_core $(ARGS)

test: setup-test
	$(PY) -m pytest -q $(PYTEST_ARGS)

plugins: setup
	$(PY) -m visphy_core plugins

ui:
	bash scripts/setup.sh ui
	.venv/bin/mlflow ui --backend-store-uri sqlite:///$(abspath $(or $(VISPHY_HOME),visphy-out))/mlflow.db

clean:
	rm -rf .venv visphy-out
