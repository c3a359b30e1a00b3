# climbd: `make test` and `make demo` work on a fresh machine with only Python and pip.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
# System libraries: libusb for pyrealsense2, iproute2 for the two-namespace network test,
# Mesa's EGL and software rasteriser for the twin's depth cameras (no GPU needed).
SYSLIBS := libusb-1.0-0 iproute2 libegl1 libegl-mesa0 libgl1-mesa-dri

.PHONY: test demo bench lint syslibs clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip 'setuptools>=77'
	$(PY) -m pip install -q -e '.[dev]'
	touch $@

syslibs:
	@missing=""; \
	ldconfig -p | grep -q 'libusb-1.0.so.0' || missing="$$missing libusb-1.0-0"; \
	command -v ip >/dev/null || missing="$$missing iproute2"; \
	ldconfig -p | grep -q 'libEGL_mesa.so.0' || missing="$$missing libegl1 libegl-mesa0 libgl1-mesa-dri"; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "installing system packages:$$missing"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; \
	  else \
	    echo "missing system packages:$$missing — run: sudo apt-get install -y$$missing"; exit 1; \
	  fi; \
	fi

# Two workers, each test file whole on one of them (CI has two cores; most tests wait on
# processes, sockets and the twin). TEST_WORKERS=0 runs the suite in this process.
TEST_WORKERS ?= 2

test: syslibs $(STAMP)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

# The WidowX in the simulated attic: the real Dynamixel driver on the twin's pty, the perception
# role on ray-cast depth, joist_climb walking toward a 10 cm joist (DEMO_SECONDS=20: up to it).
# Paper 000's attic: cross a 10 cm joist, go round an 18 cm one (about 6 min wall on 2 cores).
DEMO_SECONDS ?= 210

demo: syslibs $(STAMP)
	$(VENV)/bin/climbd run --profile robots/widowx-attic-sim.toml --role all --sim attic_paper \
	  --stepped --activate --duration $(DEMO_SECONDS) --listen tcp/127.0.0.1:17447 --quiet

bench: syslibs $(STAMP)
	@for b in bench/*.py; do echo "== $$b"; $(PY) $$b || exit 1; done

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/lint-imports

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache
