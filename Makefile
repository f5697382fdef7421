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
            python3-vtk9 python3-numpy python3-scipy

.PHONY: all squish deps run test unit asan bench meshes fuzz clean node-deps

all: squish
squish: $(BUILD)/squish

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

# install missing Debian packages (quick no-op when all are present)
deps:
	@missing=""; for p in $(APT_PKGS); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	command -v node >/dev/null 2>&1 || missing="$$missing nodejs"; \
	command -v npm >/dev/null 2>&1 || missing="$$missing npm"; \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages:$$missing"; \
	  if [ "$$(id -u)" != 0 ]; then echo "error: installing needs root; run as root or: sudo apt-get install$$missing" >&2; exit 1; fi; \
	  apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q $$missing || \
	    { echo "error: apt-get failed; check the network to the Debian mirror and retry" >&2; exit 1; }; \
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

run: deps
	@$(MAKE) --no-print-directory squish
	@echo "squish: serving on http://127.0.0.1:$${PORT:-8080}/  (Ctrl-C to stop)"
	$(BUILD)/squish serve --host 127.0.0.1 --port $${PORT:-8080} --scenes meshes/scenes --web web

test: deps node-deps
	@$(MAKE) --no-print-directory -j2 squish $(BUILD)/unit_tests $(BUILD)/san/unit_tests
	@BUILD=$(BUILD) bash tests/run.sh

bench: deps node-deps
	@$(MAKE) --no-print-directory squish
	@echo "=== step and operators"
	$(BUILD)/squish bench
	@echo "=== step bounds per shipped fixed-lod scene: Gershgorin (2^n) against sharp (Lanczos, any integer) substeps"
	@for f in meshes/scenes/*.json; do echo "$$f"; $(BUILD)/squish run $$f --frames 0 --out $(BUILD)/bench-bounds | grep "step bounds" || true; done
	@echo "=== scenes: frame-budget headroom, threads"
	$(BUILD)/squish tradeoff --bench
	@echo "=== speed against accuracy (quick grid)"
	$(BUILD)/squish tradeoff meshes/scenes/cube-poke.json --quick --out $(BUILD)/bench-tradeoff
	@echo "=== headless render, 800x600 organ"
	$(BUILD)/squish render meshes/scenes/organ.json --bench
	@echo "=== service: bytes per vertex, tool-to-frame latency, 200 viewers"
	SQUISH=$(BUILD)/squish node tests/net/bench-service.mjs --seconds 10

# regenerate the shipped level-of-detail meshes (needs gmsh; not part of `make test`)
meshes:
	@command -v gmsh >/dev/null || { echo "installing gmsh"; apt-get install -y -q gmsh; }
	bash meshes/generate.sh

# fuzz the request decoder longer than `make test` does (FUZZ_SECONDS, default 600)
fuzz: deps
	FUZZ_SECONDS=$${FUZZ_SECONDS:-600} SQUISH=$(BUILD)/squish bash tests/stages/fuzz.sh

clean:
	rm -rf $(BUILD)
