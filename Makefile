# FunREC: `make demo` and `make test` set everything up (idempotent) and run.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export MUJOCO_GL ?= egl
export PYOPENGL_PLATFORM ?= egl

.PHONY: setup demo test test-slow browser bench lint clean

# Open3D needs libusb at import time; MuJoCo's offscreen renderer needs EGL or OSMesa. apt waits up to
# 10 minutes for the package lock when another install holds it, rather than failing.
SYSTEM_LIBS := libusb-1.0-0 libegl1 libgl1 libosmesa6

$(STAMP): pyproject.toml
	@missing=""; for p in $(SYSTEM_LIBS); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing system packages:$$missing"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get -o DPkg::Lock::Timeout=600 update -qq && $$SUDO apt-get -o DPkg::Lock::Timeout=600 install -y -qq $$missing; \
	fi
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	@# Open3D's wheel is 400 MB; a dropped connection once failed CI after 5 resumes. Resume harder, and
	@# retry the whole install (wheels already complete come from pip's cache).
	for attempt in 1 2 3; do \
	  $(BIN)/python -m pip install -q --retries 10 --resume-retries 50 -e ".[test]" && break; \
	  [ $$attempt = 3 ] && exit 1; echo "pip install failed (attempt $$attempt of 3); retrying in 30 s"; sleep 30; \
	done
	touch $(STAMP)

setup: $(STAMP)

demo: $(STAMP)
	$(BIN)/funrec demo -o demo_output

test: $(STAMP)
	$(BIN)/python -m pytest -q

# The slow suite drives `funrec view` in a real headless browser (tests/test_view_browser.py).
BROWSER_PACKAGES := chromium chromium-driver

browser:
	@missing=""; for p in $(BROWSER_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing system packages:$$missing"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get -o DPkg::Lock::Timeout=600 update -qq && $$SUDO apt-get -o DPkg::Lock::Timeout=600 install -y -qq $$missing; \
	fi

test-slow: $(STAMP) browser
	$(BIN)/python -m pytest -q -m slow

bench: $(STAMP)
	$(BIN)/funrec bench --suite-dir bench_suite -o bench_report

lint: $(STAMP)
	$(BIN)/ruff check funrec funrec_robot tests demos

clean:
	rm -rf demo_output bench_report
