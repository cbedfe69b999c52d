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
DPU_HDR  := $(wildcard dpu/*.h)
CONTRACT := lcmtypes/contract.txt
GEN_C    := $(patsubst lcmtypes/%.lcm,$(GEN)/c/skelmsg_%.c,$(LCMTYPES)) $(GEN)/c/skelmsg_check.c
GEN_H    := $(GEN)/c/skelmsg_contract.h

CC      ?= gcc
CFLAGS  ?= -O2 -g
WARN    := -std=c11 -D_GNU_SOURCE -Wall -Wextra -Werror
INC      = -I$(GEN)/c -Idpu -I$(LCM_PREFIX)/include
LIBS     = -L$(LCM_PREFIX)/lib -Wl,-rpath,$(LCM_PREFIX)/lib -llcm -lpthread -lm
# lcm_coretypes.h's __int8_t_decode_array does memcpy(NULL, src, 0) for every empty int8_t
# array (lcm_malloc(0) is NULL), e.g. process_t.required of a process without inputs:
# harmless, but UBSan's nonnull-attribute check would abort every config decode.
SAN     := -fsanitize=address,undefined -fno-sanitize=nonnull-attribute -fno-omit-frame-pointer -fno-sanitize-recover=all

C_TESTS := $(patsubst tests/c/%.c,$(BUILD)/asan/%,$(wildcard tests/c/test_*.c))

.PHONY: all demo test test-c test-py test-tools lint bench soak spy clean distclean

all: $(BUILD)/skel-dpu

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
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev]'
	@touch $@

# lcm-gen comes from the wheel, so the wheel is installed before the package itself.
$(VENV)/.lcm:
	@ldconfig -p | grep -q 'libglib-2.0.so.0' || { $(call need_deb,libglib2.0-0); }
	@[ -x $(PY) ] || $(PYTHON3) -m venv $(VENV) 2>/dev/null || { rm -rf $(VENV); $(call need_deb,python3-venv); $(PYTHON3) -m venv $(VENV); }
	$(PY) -m pip install -q "$$(grep -o 'lcm==[0-9.]*' pyproject.toml)"
	@touch $@

# --- generated types (never committed, never edited) -----------------------------
# skelmsg.contract first: __init__.py, the target, is written last, so a failure leaves no target.
$(GEN)/python/skelmsg/__init__.py: $(LCMTYPES) $(CONTRACT) lcmtypes/contractgen.py | $(VENV)/.lcm
	@rm -rf $(GEN)/python $(GEN)/java && mkdir -p $(GEN)/python $(GEN)/java
	$(PY) lcmtypes/contractgen.py --python $(GEN)/python/skelmsg $(CONTRACT)
	$(LCMGEN) -p --ppath $(GEN)/python -j --jpath $(GEN)/java $(LCMTYPES)

$(GEN)/c/skelmsg_%.c: lcmtypes/%.lcm | $(VENV)/.lcm
	@mkdir -p $(GEN)/c
	$(LCMGEN) -c --c-cpath $(GEN)/c --c-hpath $(GEN)/c $<

# Length checks run before lcm-gen's decoders, which trust array lengths.
$(GEN)/c/skelmsg_check.c: lcmtypes/checkgen.py $(LCMTYPES) | $(VENV)/.lcm
	@mkdir -p $(GEN)/c
	$(PY) lcmtypes/checkgen.py --out $(GEN)/c $(LCMTYPES)

# Channel names, the default URL and the limits (lcmtypes/contract.txt), for C.
$(GEN_H): lcmtypes/contractgen.py $(CONTRACT) | $(VENV)/.lcm
	@mkdir -p $(GEN)/c
	$(PY) lcmtypes/contractgen.py --c $(GEN)/c $(CONTRACT)

# --- the DPU daemon ------------------------------------------------------------------
$(BUILD)/skel-dpu: $(DPU_SRC) $(DPU_HDR) $(GEN_C) $(GEN_H) | $(STAMP)
	$(CC) $(WARN) $(CFLAGS) $(INC) -o $@ $(DPU_SRC) $(GEN_C) $(LIBS)

# The same daemon under AddressSanitizer and UBSan, for the tests.
$(BUILD)/asan/skel-dpu: $(DPU_SRC) $(DPU_HDR) $(GEN_C) $(GEN_H) | $(STAMP)
	@mkdir -p $(BUILD)/asan
	$(CC) $(WARN) -O1 -g $(SAN) $(INC) -o $@ $(DPU_SRC) $(GEN_C) $(LIBS)

# C unit tests link every dpu/ file but main.c.
$(BUILD)/asan/test_%: tests/c/test_%.c tests/c/check.h $(DPU_SRC) $(DPU_HDR) $(GEN_C) $(GEN_H) | $(STAMP)
	@mkdir -p $(BUILD)/asan
	$(CC) $(WARN) -O1 -g $(SAN) $(INC) -Itests/c -o $@ $< $(filter-out dpu/main.c,$(DPU_SRC)) $(GEN_C) $(LIBS)

# --- what users run ----------------------------------------------------------------
demo: $(BUILD)/skel-dpu $(STAMP)
	$(VENV)/bin/skel run examples/servo.yaml --spawn --compare-paper

test: test-c test-py

test-c: $(C_TESTS)
	@set -e; for t in $(C_TESTS); do echo "== $$t"; $$t; done

test-py: $(BUILD)/skel-dpu $(BUILD)/asan/skel-dpu $(STAMP) test-tools
	$(VENV)/bin/pytest -q $(PYTEST_ARGS)

# The multi-host tests (network namespaces, root only) run ip, and nft to lose packets.
test-tools:
	@$(call want_commands,ip:iproute2 nft:nftables)

lint: $(STAMP)
	$(VENV)/bin/ruff check skeleton host analysis tests lcmtypes bench examples

# cyclictest is the wake-up baseline (Debian rt-tests).
bench: $(BUILD)/skel-dpu $(STAMP)
	@$(call want_commands,cyclictest:rt-tests)
	$(PY) bench/run.py

# SERVO for 10 minutes (CI runs the same check for 20 s): no process a period behind,
# no fault the platform does not explain.
soak: $(BUILD)/skel-dpu $(BUILD)/asan/skel-dpu $(STAMP)
	SKEL_SOAK_S=$${SKEL_SOAK_S:-600} $(VENV)/bin/pytest -q -s tests/test_soak.py

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
