# skeleton: the one entry point. `make demo` and `make test` on a fresh Debian
# machine with gcc, make and python3; everything else is installed from here
# (`make test`, as root, also what the multi-host tests run: ip and nft).

PYTHON3 ?= python3
VENV    := .venv
PY      := $(VENV)/bin/python
BUILD   := build
GEN     := $(BUILD)/gen
STAMP   := $(VENV)/.installed

# The lcm wheel ships lcm-gen, lcm-logger, liblcm and its headers under site-packages.
LCM_PREFIX = $(shell $(PY) -c 'import lcm, os; print(os.path.dirname(os.path.dirname(lcm.__file__)))')
LCMGEN     = $(LCM_PREFIX)/bin/lcm-gen

LCMTYPES := $(wildcard lcmtypes/*.lcm)
DPU_SRC  := $(wildcard dpu/*.c)
DPU_HDR  := $(wildcard dpu/*.h) include/skel_step.h
CONTRACT := lcmtypes/contract.txt
GEN_C    := $(patsubst lcmtypes/%.lcm,$(GEN)/c/skelmsg_%.c,$(LCMTYPES)) $(GEN)/c/skelmsg_check.c
GEN_H    := $(GEN)/c/skelmsg_contract.h

# V=1 prints every command; by default each build step is one short line, so that `make demo`
# on a fresh clone stays one screen.
V   ?= 0
Q   := $(if $(filter 1,$(V)),,@)
say  = $(if $(Q),@echo "  $(1)",@:)

CC      ?= gcc
CFLAGS  ?= -O2 -g
WARN    := -std=c11 -D_GNU_SOURCE -Wall -Wextra -Werror
INC      = -I$(GEN)/c -Idpu -Iinclude -I$(LCM_PREFIX)/include
LIBS     = -L$(LCM_PREFIX)/lib -Wl,-rpath,$(LCM_PREFIX)/lib -llcm -lsodium -lpthread -lm -ldl
# lcm_coretypes.h's __int8_t_decode_array does memcpy(NULL, src, 0) for every empty int8_t
# array (lcm_malloc(0) is NULL), e.g. process_t.required of a process without inputs:
# harmless, but UBSan's nonnull-attribute check would abort every config decode.
SAN     := -fsanitize=address,undefined -fno-sanitize=nonnull-attribute -fno-omit-frame-pointer -fno-sanitize-recover=all

C_TESTS := $(patsubst tests/c/%.c,$(BUILD)/asan/%,$(wildcard tests/c/test_*.c))

.PHONY: all demo test test-c test-py test-tools test-fuzz fuzz fuzz-tools lint docs bench soak spy clean distclean

all: $(BUILD)/skel-dpu $(BUILD)/examples/libsum.so $(BUILD)/examples/libarm.so

# --- set-up --------------------------------------------------------------------
# Debian splits venv support and liblcm needs glib: install them when we may (root, CI),
# otherwise say exactly what to install.
define need_deb
	if [ "$$(id -u)" = 0 ]; then apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(1); \
	else echo "skeleton needs the Debian package(s) $(1): sudo apt-get install $(1)" >&2; exit 1; fi
endef

# Commands some tests or benchmarks run (`command:package ...`): installed when missing if we
# are root with apt-get; otherwise the tests that need them skip and say why.
define want_commands
	if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then missing=""; \
	for pair in $(1); do command -v "$${pair%%:*}" >/dev/null || missing="$$missing $${pair#*:}"; done; \
	if [ -n "$$missing" ]; then apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing; fi; fi
endef

$(STAMP): pyproject.toml $(GEN)/python/skelmsg/__init__.py
	@ldconfig -p | grep -q 'libglib-2.0.so.0' || { $(call need_deb,libglib2.0-0); }
	@[ -x $(PY) ] || $(PYTHON3) -m venv $(VENV) 2>/dev/null || { rm -rf $(VENV); $(call need_deb,python3-venv); $(PYTHON3) -m venv $(VENV); }
	$(call say,PIP   $(VENV))
	$(Q)$(PY) -m pip install -q --upgrade pip
	$(Q)$(PY) -m pip install $(if $(Q),-qq,-q) -e '.[dev]'
	@touch $@

# lcm-gen comes from the wheel, so the wheel is installed before the package itself.
$(VENV)/.lcm:
	@ldconfig -p | grep -q 'libglib-2.0.so.0' || { $(call need_deb,libglib2.0-0); }
	@[ -x $(PY) ] || $(PYTHON3) -m venv $(VENV) 2>/dev/null || { rm -rf $(VENV); $(call need_deb,python3-venv); $(PYTHON3) -m venv $(VENV); }
	$(call say,PIP   $(VENV))
	$(Q)$(PY) -m pip install -q "$$(grep -o 'lcm==[0-9.]*' pyproject.toml)"
	@touch $@

# --- generated types (never committed, never edited) -----------------------------
# skelmsg.contract first: __init__.py, the target, is written last, so a failure leaves no target.
$(GEN)/python/skelmsg/__init__.py: $(LCMTYPES) $(CONTRACT) lcmtypes/contractgen.py | $(VENV)/.lcm
	@rm -rf $(GEN)/python $(GEN)/java && mkdir -p $(GEN)/python $(GEN)/java
	$(call say,GEN   $(GEN)/python)
	$(Q)$(PY) lcmtypes/contractgen.py --python $(GEN)/python/skelmsg $(CONTRACT)
	$(call say,LCMGEN $(GEN)/python $(GEN)/java)
	$(Q)$(LCMGEN) -p --ppath $(GEN)/python -j --jpath $(GEN)/java $(LCMTYPES)

$(GEN)/c/skelmsg_%.c: lcmtypes/%.lcm | $(VENV)/.lcm
	@mkdir -p $(GEN)/c
	$(Q)$(LCMGEN) -c --c-cpath $(GEN)/c --c-hpath $(GEN)/c $<

# Length checks run before lcm-gen's decoders, which trust array lengths.
$(GEN)/c/skelmsg_check.c: lcmtypes/checkgen.py $(LCMTYPES) | $(VENV)/.lcm
	@mkdir -p $(GEN)/c
	$(call say,GEN   $(GEN)/c)
	$(Q)$(PY) lcmtypes/checkgen.py --out $(GEN)/c $(LCMTYPES)

# Channel names, the default URL and the limits (lcmtypes/contract.txt), for C.
$(GEN_H): lcmtypes/contractgen.py $(CONTRACT) $(LCMTYPES) | $(VENV)/.lcm
	@mkdir -p $(GEN)/c
	$(call say,GEN   $@)
	$(Q)$(PY) lcmtypes/contractgen.py --c $(GEN)/c $(CONTRACT)

# --- the DPU daemon ------------------------------------------------------------------
# libsodium computes the HMACs of signed control (dpu/seal.c).
SODIUM := $(BUILD)/.sodium
$(SODIUM):
	@[ -f /usr/include/sodium.h ] || { $(call need_deb,libsodium-dev); }
	@mkdir -p $(BUILD) && touch $@

$(BUILD)/skel-dpu: $(DPU_SRC) $(DPU_HDR) $(GEN_C) $(GEN_H) | $(STAMP) $(SODIUM)
	$(call say,CC    $@)
	$(Q)$(CC) $(WARN) $(CFLAGS) $(INC) -o $@ $(DPU_SRC) $(GEN_C) $(LIBS)

# The same daemon under AddressSanitizer and UBSan, for the tests. dpu/ and the generated
# code are compiled once (build/asan/obj) and linked into the daemon and every C unit test:
# compiled per test they took minutes of `make test`. DPU_LIB: what every C unit test and
# fuzz harness links, dpu/ but main.c, and the generated code.
DPU_LIB    = $(notdir $(filter-out dpu/main.c,$(DPU_SRC)) $(GEN_C))
ASAN_OBJ  := $(BUILD)/asan/obj
ASAN_OBJS  = $(patsubst %.c,$(ASAN_OBJ)/%.o,$(DPU_LIB))
.PRECIOUS: $(ASAN_OBJ)/%.o

$(ASAN_OBJ)/%.o: dpu/%.c $(DPU_HDR) $(GEN_H) $(GEN_C) | $(STAMP) $(SODIUM)
	@mkdir -p $(@D)
	$(call say,CC    $@)
	$(Q)$(CC) $(WARN) -O1 -g $(SAN) $(INC) -c -o $@ $<

$(ASAN_OBJ)/%.o: $(GEN)/c/%.c $(GEN_C) | $(STAMP)
	@mkdir -p $(@D)
	$(call say,CC    $@)
	$(Q)$(CC) $(WARN) -O1 -g $(SAN) $(INC) -c -o $@ $<

$(BUILD)/asan/skel-dpu: $(ASAN_OBJ)/main.o $(ASAN_OBJS)
	$(call say,CC    $@)
	$(Q)$(CC) $(SAN) -o $@ $^ $(LIBS)

$(BUILD)/asan/test_%: tests/c/test_%.c tests/c/check.h $(ASAN_OBJS)
	$(call say,CC    $@)
	$(Q)$(CC) $(WARN) -O1 -g $(SAN) $(INC) -Itests/c -o $@ $< $(ASAN_OBJS) $(LIBS)

# The example of real code (examples/code/sum.c), built as anyone builds theirs: the header alone.
$(BUILD)/examples/libsum.so: examples/code/sum.c include/skel_step.h
	@mkdir -p $(@D)
	$(call say,CC    $@)
	$(Q)$(CC) $(WARN) $(CFLAGS) -fPIC -shared -Iinclude -o $@ $<

# SERVO's kinematics as real code (examples/code/arm.c, examples/servo-code.yaml).
$(BUILD)/examples/libarm.so: examples/code/arm.c include/skel_step.h
	@mkdir -p $(@D)
	$(call say,CC    $@)
	$(Q)$(CC) $(WARN) $(CFLAGS) -fPIC -shared -Iinclude -o $@ $< -lm

# test_code loads the example library.
$(BUILD)/asan/test_code: $(BUILD)/examples/libsum.so

# Hostile traffic for the flood test and `make bench` (tests/flood/flood.c).
$(BUILD)/flood: tests/flood/flood.c $(GEN_C) | $(STAMP)
	$(call say,CC    $@)
	$(Q)$(CC) $(WARN) -O2 $(INC) -o $@ $< $(filter-out $(GEN)/c/skelmsg_check.c,$(GEN_C)) $(LIBS)

# The timing harness's witness of the platform (tests/steal.py, tests/probe/probe.c).
$(BUILD)/probe: tests/probe/probe.c
	$(call say,CC    $@)
	$(Q)$(CC) $(WARN) -O2 -o $@ $<

# --- what users run ----------------------------------------------------------------
# DEMO_ARGS: e.g. a private --url and --out, as the test of the demo gives.
demo: $(BUILD)/skel-dpu $(STAMP)
	@$(VENV)/bin/skel run examples/servo.yaml --spawn --compare-paper $(DEMO_ARGS)

test: test-c test-fuzz test-py

test-c: $(C_TESTS)
	@set -e; for t in $(C_TESTS); do echo "== $$t"; $$t; done

test-py: $(BUILD)/skel-dpu $(BUILD)/asan/skel-dpu $(BUILD)/examples/libsum.so $(BUILD)/examples/libarm.so $(BUILD)/flood $(BUILD)/probe $(STAMP) test-tools
	$(VENV)/bin/pytest -q -rfEs --durations=15 $(PYTEST_ARGS)

# The multi-host tests (network namespaces, root only) run ip, and nft to lose packets; the
# console's browser tests (tests/e2e/test_console_browser.py) drive Debian's headless Chromium.
test-tools:
	@$(call want_commands,ip:iproute2 nft:nftables chromium:chromium chromedriver:chromium-driver)

# --- fuzzing: libFuzzer harnesses, one per path from received bytes to DPU state ----------
# clang and its runtimes (Debian: clang, libclang-rt-14-dev) build them; installed as root,
# otherwise the one apt-get line is printed. dpu/ and the generated code are compiled once
# with coverage (fuzzer-no-link) and linked into each harness (tests/fuzz/fuzz_<name>.c).
FUZZ_CC            ?= clang
FUZZ_SECONDS       ?= 600
FUZZ_SMOKE_SECONDS ?= 12
FUZZ_HARNESSES     := buffer event config command seal
FUZZ_DIR           := $(BUILD)/fuzz
FUZZ_BINS          := $(patsubst %,$(FUZZ_DIR)/fuzz_%,$(FUZZ_HARNESSES))
# nonnull-attribute: lcm_coretypes.h's memcpy(NULL, src, 0), as for SAN above.
FUZZ_SAN    := -DFUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION -fsanitize=address,undefined -fno-sanitize=nonnull-attribute -fno-sanitize-recover=all \
               -fno-omit-frame-pointer
FUZZ_OBJS    = $(patsubst %.c,$(FUZZ_DIR)/obj/%.o,$(DPU_LIB))
.PRECIOUS: $(FUZZ_DIR)/obj/%.o
# -close_fd_mask=2: the DPU's log lines (one per command) would drown libFuzzer's; sanitizer
# reports still reach the terminal. -timeout: an input that takes 5 s is a hang, reported.
FUZZ_RUN    := -close_fd_mask=2 -timeout=5 -print_final_stats=1

fuzz-tools:
	@command -v $(FUZZ_CC) >/dev/null && \
	  [ -f "$$($(FUZZ_CC) -print-runtime-dir)/libclang_rt.fuzzer-$$(uname -m).a" ] || \
	  { $(call need_deb,clang libclang-rt-14-dev); }

$(FUZZ_DIR)/obj/%.o: dpu/%.c $(DPU_HDR) $(GEN_H) $(GEN_C) | fuzz-tools $(STAMP)
	@mkdir -p $(@D)
	$(call say,CLANG $@)
	$(Q)$(FUZZ_CC) $(WARN) -O1 -g -fsanitize=fuzzer-no-link $(FUZZ_SAN) $(INC) -c -o $@ $<

$(FUZZ_DIR)/obj/%.o: $(GEN)/c/%.c $(GEN_C) | fuzz-tools $(STAMP)
	@mkdir -p $(@D)
	$(call say,CLANG $@)
	$(Q)$(FUZZ_CC) $(WARN) -O1 -g -fsanitize=fuzzer-no-link $(FUZZ_SAN) $(INC) -c -o $@ $<

$(FUZZ_DIR)/fuzz_%: tests/fuzz/fuzz_%.c tests/fuzz/fuzz.c tests/fuzz/fuzz.h tests/c/fixture.h $(FUZZ_OBJS) | fuzz-tools
	$(call say,CLANG $@)
	$(Q)$(FUZZ_CC) $(WARN) -O1 -g -fsanitize=fuzzer $(FUZZ_SAN) $(INC) -Itests/fuzz -Itests/c -o $@ \
	  $< tests/fuzz/fuzz.c $(FUZZ_OBJS) $(LIBS)

# One harness ($(1)): the regressions replayed once (a file that crashes fails at once), then
# fuzzing from the seed corpus and the regressions for $(2) seconds, run by $(3) (nice). New
# inputs go to build/fuzz/corpus/<name> (read back next time), crashes to
# build/fuzz/artifacts/<name>/: never into the repository's tree.
define fuzz_one
	@set -e; h=$(1); \
	  mkdir -p $(FUZZ_DIR)/corpus/$$h $(FUZZ_DIR)/artifacts/$$h; \
	  reg=$$(find tests/fuzz/regressions/$$h -type f 2>/dev/null | sort); \
	  if [ -n "$$reg" ]; then echo "== fuzz_$$h: $$(echo "$$reg" | wc -l) regression(s)"; \
	    $(FUZZ_DIR)/fuzz_$$h $(FUZZ_RUN) -artifact_prefix=$(FUZZ_DIR)/artifacts/$$h/ $$reg; fi; \
	  echo "== fuzz_$$h: $(2) s"; \
	  $(3) $(FUZZ_DIR)/fuzz_$$h $(FUZZ_RUN) -max_total_time=$(2) \
	    -artifact_prefix=$(FUZZ_DIR)/artifacts/$$h/ $(FUZZ_DIR)/corpus/$$h tests/fuzz/corpus/$$h \
	    $$( [ -d tests/fuzz/regressions/$$h ] && echo tests/fuzz/regressions/$$h )
endef

# The smoke, part of `make test`: every harness for FUZZ_SMOKE_SECONDS (default 12), two at a
# time on two cores (one at a time took 100 s of CI), each one's output kept together.
test-fuzz: $(FUZZ_BINS)
	@$(MAKE) --no-print-directory -j2 -Otarget $(FUZZ_HARNESSES:%=fuzz-smoke-%)

fuzz-smoke-%: $(FUZZ_DIR)/fuzz_%
	$(call fuzz_one,$*,$(FUZZ_SMOKE_SECONDS),)

fuzz-long-%: $(FUZZ_DIR)/fuzz_%
	$(call fuzz_one,$*,$(FUZZ_SECONDS),nice -n 19)

# Long fuzzing, niced for a shared machine: each harness for FUZZ_SECONDS (default 600), one
# at a time, then the Hypothesis properties with their long profile (tests/conftest.py).
fuzz: $(FUZZ_BINS) $(STAMP)
	@$(MAKE) --no-print-directory -j1 $(FUZZ_HARNESSES:%=fuzz-long-%)
	SKEL_HYPOTHESIS=fuzz nice -n 19 $(VENV)/bin/pytest -q -p no:cacheprovider \
	  tests/unit/test_system_properties.py tests/unit/test_logreader_properties.py tests/unit/test_stats_properties.py

lint: $(STAMP)
	$(VENV)/bin/ruff check skeleton host analysis tests lcmtypes bench examples docs

# The documentation site (MkDocs, Material): warnings are errors, and the reference pages are
# generated from the code as it builds (docs/hooks.py). `make test` builds it too
# (tests/docs/test_site.py) and runs the shell blocks of the tutorial and how-to pages.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --site-dir $(BUILD)/site

# cyclictest is the wake-up baseline (Debian rt-tests).
# PARTS=a,b runs only those parts (bench/run.py --parts)
bench: $(BUILD)/skel-dpu $(BUILD)/flood $(STAMP)
	@$(call want_commands,cyclictest:rt-tests)
	$(PY) bench/run.py $(if $(PARTS),--parts $(PARTS))

# SERVO for 10 minutes (CI runs the same check for 20 s): no process a period behind,
# no fault the platform does not explain.
soak: $(BUILD)/skel-dpu $(BUILD)/asan/skel-dpu $(STAMP)
	SKEL_SOAK_S=$${SKEL_SOAK_S:-600} $(VENV)/bin/pytest -q -s tests/e2e/test_soak.py

# A jar of the generated types, so lcm-spy decodes every channel (one lcm-gen run writes
# the Python and the Java types). lcm-spy's window needs a display and a full Java runtime.
$(BUILD)/skelmsg.jar: $(GEN)/python/skelmsg/__init__.py
	@command -v javac >/dev/null || { $(call need_deb,default-jdk-headless); }
	@rm -rf $(BUILD)/java && mkdir -p $(BUILD)/java
	javac -nowarn -cp $(LCM_PREFIX)/share/java/lcm.jar -d $(BUILD)/java $(GEN)/java/skelmsg/*.java
	jar cf $@ -C $(BUILD)/java .

spy: $(BUILD)/skelmsg.jar
	CLASSPATH=$(abspath $(BUILD)/skelmsg.jar) $(LCM_PREFIX)/bin/lcm-spy $(if $(URL),--lcm-url=$(URL))

clean:
	rm -rf $(BUILD)

distclean: clean
	rm -rf $(VENV) runs
