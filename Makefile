# squish - build, install, test.  The README's two commands: `make run` and `make test`.
# Both install what is missing on a Debian 12 machine (as root), then build.

BUILD    ?= build
CC       ?= gcc
PKGS     := libwebsockets libcjson zlib osmesa libpng
OPT      ?= -O3 -march=x86-64-v3
CFLAGS   ?= $(OPT) -g
CFLAGS   += -std=c11 -Wall -Wextra -D_GNU_SOURCE -Iserver -MMD -MP
CFLAGS   += $(shell pkg-config --cflags $(PKGS) 2>/dev/null)
LDLIBS   += $(shell pkg-config --libs $(PKGS) 2>/dev/null) -lm -lpthread
PREFIX   ?= /usr/local
DATADIR  := $(PREFIX)/share/squish
CFLAGS   += -DSQ_DATADIR='"$(DATADIR)"'
SAN      := -O1 -g -fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=undefined

LIB_SRC  := $(sort $(filter-out server/app/%,$(wildcard server/*/*.c)))
APP_SRC  := $(sort $(wildcard server/app/*.c))
TEST_SRC := $(sort $(wildcard tests/unit/*.c))

LIB_OBJ  := $(LIB_SRC:%.c=$(BUILD)/obj/%.o)
APP_OBJ  := $(APP_SRC:%.c=$(BUILD)/obj/%.o)
TEST_OBJ := $(TEST_SRC:%.c=$(BUILD)/obj/%.o)
SAN_OBJ  := $(LIB_SRC:%.c=$(BUILD)/san/%.o) $(TEST_SRC:%.c=$(BUILD)/san/%.o)

# Debian packages the build, the tests and the benchmarks need
APT_PKGS := build-essential pkg-config libwebsockets-dev libcjson-dev zlib1g-dev libosmesa6-dev \
            libpng-dev clang libclang-rt-14-dev gnuplot-nox chromium hyperfine \
            python3-vtk9 nginx python3-websockets python3-numpy python3-scipy

.PHONY: all squish layers deps run test unit asan bench meshes fuzz clean node-deps install uninstall

all: squish
squish: layers $(BUILD)/squish

# the include rule of server/ (docs/architecture.md): an include up or across the layers fails the build
layers:
	@bash tests/layers.sh server

$(BUILD)/squish: $(APP_OBJ) $(LIB_OBJ)
	$(CC) $(CFLAGS) -o $@ $^ $(LDLIBS)

$(BUILD)/unit_tests: $(TEST_OBJ) $(LIB_OBJ)
	$(CC) $(CFLAGS) -o $@ $^ $(LDLIBS)

$(BUILD)/san/unit_tests: $(SAN_OBJ)
	$(CC) $(SAN) -o $@ $^ $(LDLIBS)

$(BUILD)/obj/%.o: %.c
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) -c -o $@ $<

$(BUILD)/san/%.o: %.c
	@mkdir -p $(dir $@)
	$(CC) $(filter-out $(OPT) -g,$(CFLAGS)) $(SAN) -c -o $@ $<

-include $(shell find $(BUILD) -name '*.d' 2>/dev/null)

# install missing Debian packages (quick no-op when all are present); services they ship
# (nginx) are not started: a temporary policy-rc.d denies it, the tests start their own
deps:
	@missing=""; for p in $(APT_PKGS); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	command -v node >/dev/null 2>&1 || missing="$$missing nodejs"; \
	command -v npm >/dev/null 2>&1 || missing="$$missing npm"; \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages:$$missing"; \
	  if [ "$$(id -u)" != 0 ]; then echo "error: installing needs root; run as root or: sudo apt-get install$$missing" >&2; exit 1; fi; \
	  norc=; if [ ! -e /usr/sbin/policy-rc.d ]; then norc=1; printf '#!/bin/sh\nexit 101\n' >/usr/sbin/policy-rc.d; \
	    chmod +x /usr/sbin/policy-rc.d; fi; \
	  apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q $$missing; rc=$$?; \
	  if [ -n "$$norc" ]; then rm -f /usr/sbin/policy-rc.d; fi; \
	  [ $$rc = 0 ] || { echo "error: apt-get failed; check the network to the Debian mirror and retry" >&2; exit 1; }; \
	fi

# npm packages for the protocol and browser tests (ws, playwright-core), from tests/package-lock.json
node-deps: deps
	@if [ -f tests/package.json ]; then \
	  if [ ! -d tests/node_modules ] || [ tests/package-lock.json -nt tests/node_modules/.package-lock.json ]; then \
	    echo "installing npm packages in tests/"; cd tests && npm ci --no-audit --no-fund --loglevel=error; \
	  fi; fi

unit: $(BUILD)/unit_tests
	$(BUILD)/unit_tests

asan: $(BUILD)/san/unit_tests
	ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 $(BUILD)/san/unit_tests

# the viewer (web/) and the shipped scenes (meshes/scenes) are found next to the binary's tree
run: deps
	@$(MAKE) --no-print-directory squish
	@$(MAKE) --no-print-directory node-deps || echo "warning: npm packages not installed (needed by the Node client examples only): retry with make node-deps"
	@echo "squish: serving on http://127.0.0.1:$${PORT:-8080}/  (Ctrl-C to stop)"
	$(BUILD)/squish serve --host 127.0.0.1 --port $${PORT:-8080}

# $(DESTDIR)$(PREFIX)/bin/squish and $(DESTDIR)$(DATADIR)/{web,scenes,meshes}. The scene files
# name their meshes "../<shape>/..." (meshes/scenes next to meshes/<shape>); installed they sit
# in share/squish/scenes next to share/squish/meshes, so those paths become "../meshes/<shape>/".
install: squish
	install -d $(DESTDIR)$(PREFIX)/bin $(DESTDIR)$(DATADIR)/web $(DESTDIR)$(DATADIR)/scenes \
	  $(DESTDIR)$(DATADIR)/meshes
	install -m 755 $(BUILD)/squish $(DESTDIR)$(PREFIX)/bin/squish
	install -m 644 $(wildcard web/*.*) $(DESTDIR)$(DATADIR)/web/
	@set -e; for d in meshes/*/; do d=$${d%/}; n=$${d#meshes/}; [ "$$n" = scenes ] && continue; \
	  echo "install $$d -> $(DESTDIR)$(DATADIR)/meshes/$$n"; \
	  install -d $(DESTDIR)$(DATADIR)/meshes/$$n; \
	  install -m 644 $$(ls $$d/*.msh $$d/*.obj $$d/*.stl 2>/dev/null) $(DESTDIR)$(DATADIR)/meshes/$$n/; done
	@set -e; for f in meshes/scenes/*.json; do \
	  echo "install $$f -> $(DESTDIR)$(DATADIR)/scenes/ (mesh paths ../X/ -> ../meshes/X/)"; \
	  sed 's#"\.\./\([A-Za-z0-9_-]*\)/#"../meshes/\1/#g' $$f > $(DESTDIR)$(DATADIR)/scenes/$${f##*/}; \
	  chmod 644 $(DESTDIR)$(DATADIR)/scenes/$${f##*/}; done
	@echo "installed: $(DESTDIR)$(PREFIX)/bin/squish; viewer, scenes and meshes in $(DESTDIR)$(DATADIR)"

uninstall:
	rm -f $(DESTDIR)$(PREFIX)/bin/squish
	rm -rf $(DESTDIR)$(DATADIR)

test: deps node-deps
	@$(MAKE) --no-print-directory -j2 squish $(BUILD)/unit_tests $(BUILD)/san/unit_tests
	@BUILD=$(BUILD) bash tests/run.sh

bench: deps node-deps
	@$(MAKE) --no-print-directory squish
	@echo "=== step and operators"
	$(BUILD)/squish bench
	@echo "=== step bounds per shipped fixed-lod scene: Gershgorin (2^n) against sharp (Lanczos, any integer) substeps"
	@for f in meshes/scenes/*.json; do echo "$$f"; $(BUILD)/squish run $$f --frames 0 --out $(BUILD)/bench-bounds | grep "step bounds" || true; done
	@echo "=== the implicit integrator: SOFA reference beam, stiff cantilever, preconditioners (a minute)"
	$(BUILD)/squish bench implicit
	@echo "=== contact: a 10k-node box on a tray mesh and on a plane, the shipped contact scenes"
	$(BUILD)/squish bench contact
	@echo "=== scenes: frame-budget headroom, threads"
	$(BUILD)/squish tradeoff --bench
	@echo "=== speed against accuracy (quick grid)"
	$(BUILD)/squish tradeoff meshes/scenes/cube-poke.json --quick --out $(BUILD)/bench-tradeoff
	@echo "=== the adaptive headline: box-big (117,649 finest nodes), adaptive against fixed levels, and 3 runs with the live budget (the guard) beside fixed L2 and fixed finest with the three aims met or not (minutes)"
	@if [ -f meshes/box/box_48.msh ]; then \
	  $(BUILD)/squish tradeoff --bench --scene meshes/scenes/box-big.json && \
	  $(BUILD)/squish tradeoff meshes/scenes/box-big.json --quick --reference-step 0.9 --out $(BUILD)/bench-box-big; \
	else echo "skipped: box-big's meshes are not made; run 'make meshes' first"; fi
	@echo "=== headless render, 800x600 organ"
	$(BUILD)/squish render meshes/scenes/organ.json --bench
	@echo "=== service: bytes per vertex, tool-to-frame latency, 200 viewers"
	SQUISH=$(BUILD)/squish node tests/net/bench-service.mjs --seconds 10
	@echo "=== haptic channel: pose-in to force-out at 1 kHz, 20 viewers, frame CPU with and without it"
	SQUISH=$(BUILD)/squish node tests/net/bench-haptic.mjs --viewers 20 --seconds 5 --rounds 2
	@echo "=== haptic model accuracy: force at mid-frame against a 500 Hz reference, slow press, cube-poke and organ"
	SQUISH=$(BUILD)/squish /usr/bin/python3 tests/net/haptic_accuracy.py
	@echo "=== haptic loop passivity: simulated devices of 0.1, 0.2, 0.4 kg over three coupling stiffnesses each"
	SQUISH=$(BUILD)/squish /usr/bin/python3 tests/net/haptic_sweep.py

# regenerate the shipped level-of-detail meshes (needs gmsh; not part of `make test`)
# the generated family (meshes/box: box-big.json's levels, made by squish itself; its fine levels
# are too large for git). The committed Gmsh families: bash meshes/generate.sh cube sphere beam organ
meshes: squish
	SQUISH=$(BUILD)/squish bash meshes/generate.sh

# fuzz every parser longer than `make test` does: FUZZ_SECONDS per harness (default 300, six
# harnesses: 30 min), FUZZ_ONLY="msh scene" for a subset (tests/stages/fuzz.sh)
fuzz: deps
	FUZZ_SECONDS=$${FUZZ_SECONDS:-300} SQUISH=$(BUILD)/squish bash tests/stages/fuzz.sh

clean:
	rm -rf $(BUILD)
