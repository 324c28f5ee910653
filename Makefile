# voxd — build, test, bench, demo.
#
#   make            release build: build/release/{vox,libvoxd.a}
#   make test       unit (Criterion), integration and fuzz-corpus suites under
#                   AddressSanitizer + UndefinedBehaviorSanitizer; ends in "N passed, N failed"
#   make demo       installs missing Debian packages, builds, voxelizes Scene 1,
#                   writes scene1.vod and scene1.png
#   make bench      benchmarks (release build): voxbench (embedded engine),
#                   voxdbench (through a voxd it starts), the whole vox
#                   voxelize command (scripts/bench-whole.sh), vox export
#                   (scripts/bench-export.sh) and vox mesh in the layout of the
#                   Isovox thesis's Tables 6-9 (scripts/bench-iso.sh), tables
#                   in bench/results/
#   make bench-mpi  vox_mpi on 1, 2 and 4 ranks over TCP against vox voxelize
#                   (scripts/bench-mpi.sh; make bench runs it too)
#   make bench-mesh the mesh loaders on the Stanford dragon and bunny (npm models)
#                   and the whole vox voxelize --mesh command (scripts/bench-mesh-whole.sh)
#   make bench-csg  the vox csg command: the thesis's Tables 3/4 layout and the
#                   CSG kind at 512^3 and 1024^3 with 1 and 2 workers (scripts/bench-csg.sh)
#   make bench-scale every kind of job (implicit, mesh, CSG, marching cubes)
#                   from 1 worker to one per core (scripts/bench-scale.sh)
#   make bench-serial the serial share of six jobs with 2 workers, measured
#                   from outside by bench/voxserial (scripts/bench-serial.sh)
#   make fuzz       libFuzzer on every harness for FUZZ_SECONDS each
#   make deps       installs the Debian packages the build needs, if missing

CC      ?= cc
CXX     ?= g++
PREFIX  ?= /usr/local
V       ?= release
BUILD   ?= build/$(V)
PKGS    := zlib libdeflate libpng libxxhash libuv libprotobuf-c json-c

# PKG_CFLAGS and PKG_LIBS: scripts/configure asks pkg-config for them and writes
# $(CONFIG), which make makes, then reads by starting over. Asking while make
# reads this file would be too early on a fresh machine, where `make demo`
# installs pkg-config and the libraries only when its deps prerequisite runs.
# So the goals that install (DEPS_GOALS: every goal with deps as a prerequisite)
# run deps before configuring; the others stop with the missing package's name.
DEPS_GOALS := deps test demo bench bench-compare
CONFIG  := $(BUILD)/config.mk
.DEFAULT_GOAL := all
ifneq ($(filter-out clean deps,$(or $(MAKECMDGOALS),all)),)
include $(CONFIG)
endif
$(CONFIG): scripts/configure Makefile | $(if $(filter $(DEPS_GOALS),$(MAKECMDGOALS)),deps)
	@mkdir -p $(dir $@)
	@scripts/configure $(PKGS) >$@.tmp || { rm -f $@.tmp; exit 1; }
	@mv $@.tmp $@

WARN    := -Wall -Wextra -Werror -Wshadow -Wstrict-prototypes -Wmissing-prototypes -Wvla
CSTD    := -std=c11 -D_GNU_SOURCE
# One folder per module.  LAYER_x lists the folders module x may include
# from: each module compiles with those include paths only, so an include
# against the layering does not compile (tests/integration/layering.sh
# checks the same over the sources, and that no two files include each
# other).  The data flows down this list; nothing includes upwards.
MODULES := mpi client daemon config libvox engine worker subdiv shm csg iso mesh proto vod octree expr ival common
LAYER_mpi    := client config libvox engine worker subdiv shm csg iso mesh proto expr ival vod octree common
LAYER_client := config libvox engine csg iso mesh proto expr ival vod octree common
LAYER_daemon := config engine shm csg iso mesh proto libvox expr ival vod octree common
LAYER_config := proto expr ival common
LAYER_libvox := proto common
LAYER_engine := worker subdiv shm csg iso mesh expr ival vod octree common
LAYER_worker := subdiv shm csg iso mesh expr ival vod octree common
LAYER_subdiv := expr ival octree common
LAYER_shm    := iso mesh vod octree common
LAYER_csg    := mesh expr ival vod octree common
LAYER_iso    := vod octree common
LAYER_mesh   := vod octree common
LAYER_proto  := common
LAYER_vod    := octree common
LAYER_octree :=
LAYER_expr   := ival common
LAYER_ival   :=
LAYER_common :=
# -I flags of module $(1): itself, its layers, and the generated protocol
# headers for those that may include proto/.
modinc = $(patsubst %,-I%,$(1) $(LAYER_$(1))) $(if $(filter proto,$(1) $(LAYER_$(1))),-I$(BUILD)/proto)
INC     := $(patsubst %,-I%,$(MODULES)) -I$(BUILD)/proto
SAN_OPT := -fno-omit-frame-pointer -fsanitize=address,undefined -fno-sanitize-recover=undefined
# VDB_OPT: the C++ shim's (client/vdb_out.cc, below).  Its compiler spends
# its time on OpenVDB's templates, not on our 250 lines: at -O1 -g with the
# sanitizers it took 2 minutes, the asan build's longest job and its last
# (the whole build 2m41s on 2 cores); at -O0 -g1 47 s with the same
# sanitizers, and in release 36 s at -O2 -g1 against 52 s at -O2 -g.  Line
# tables are all its stack traces need.
ifeq ($(V),release)
  OPT     := -O2 -g
  VDB_OPT := -O2 -g1
else ifeq ($(V),asan)
  OPT     := -O1 -g $(SAN_OPT)
  VDB_OPT := -O0 -g1 $(SAN_OPT)
else ifeq ($(V),debug)
  OPT     := -O0 -g
  VDB_OPT := -O0 -g
endif
CFLAGS  += $(CSTD) $(WARN) $(OPT) $(PKG_CFLAGS) -MMD -MP
# --version of vox and voxd: the version and the git commit built from
# ("unknown" outside git); the stamp rebuilds the two objects on a new commit.
VOX_VERSION := 0.1
VOX_COMMIT  := $(or $(shell git rev-parse --short=12 HEAD 2>/dev/null),unknown)
VERSION_OBJ := $(BUILD)/client/cli_msg.o $(BUILD)/daemon/voxd.o
$(VERSION_OBJ): CFLAGS += -DVOX_VERSION='"$(VOX_VERSION)"' -DVOX_COMMIT='"$(VOX_COMMIT)"'
$(VERSION_OBJ): $(BUILD)/commit.stamp
$(BUILD)/commit.stamp: FORCE
	@mkdir -p $(@D); echo '$(VOX_COMMIT)' | cmp -s - $@ || echo '$(VOX_COMMIT)' > $@
FORCE:
LDFLAGS += $(filter -fsanitize=%,$(OPT))
LDLIBS  += $(PKG_LIBS) -lm -lpthread -lrt

LIB_SRC ?= $(wildcard $(MODULES:%=%/*.c))
LIB_SRC := $(filter-out client/vox.c daemon/voxd.c mpi/vox_mpi%.c,$(LIB_SRC))
# libvox, the client library: only what a client needs (vox.h, framing,
# the protocol), an archive of its own with a pkg-config file.
LIBVOX_SRC := $(wildcard libvox/*.c proto/*.c) common/outfile.c common/job_meta.c common/err.c
LIBVOX_OBJ = $(LIBVOX_SRC:%.c=$(BUILD)/%.o) $(PROTO_C:.c=.o)
LIBVOX     := $(BUILD)/libvox.a
# ... and a shared library of the same sources built position-independent
# (in $(BUILD)/pic), exporting vox.h's calls alone (libvox/libvox.map);
# its soname, libvox.so.$(LIBVOX_MAJOR), changes when vox.h's interface does.
LIBVOX_MAJOR := 1
LIBVOX_SO    := $(BUILD)/libvox.so.$(LIBVOX_MAJOR).0.0
LIBVOX_PIC    = $(LIBVOX_SRC:%.c=$(BUILD)/pic/%.o) $(PROTO_C:$(BUILD)/%.c=$(BUILD)/pic/%.o)
PROTO   := $(wildcard proto/*.proto)
PROTO_C := $(PROTO:proto/%.proto=$(BUILD)/proto/%.pb-c.c)
LIB_OBJ := $(LIB_SRC:%.c=$(BUILD)/%.o) $(PROTO_C:.c=.o)
LIB     := $(BUILD)/libvoxd.a
BINS    := $(BUILD)/vox $(BUILD)/vox-vdb.so $(if $(wildcard daemon/voxd.c),$(BUILD)/voxd) $(LIBVOX) $(LIBVOX_SO) $(BUILD)/libvox.pc \
           $(BUILD)/vox_mpi

UNIT_SRC := $(wildcard tests/unit/test_*.c)
UNIT_BIN := $(UNIT_SRC:tests/unit/%.c=$(BUILD)/tests/%)
FUZZ_SRC := $(wildcard tests/fuzz/fuzz_*.c)

# Keep generated protobuf-c sources: make would delete them as intermediates.
.SECONDARY:

.PHONY: all deps test test-build demo bench bench-compare bench-mesh bench-mpi bench-csg bench-scale bench-serial bench-build fuzz clean
all: $(BINS)

$(BUILD)/%.o: %.c | $(PROTO_C)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) $(call modinc,$(firstword $(subst /, ,$*))) -c $< -o $@

# Generated protobuf-c code is built, never committed.
$(BUILD)/proto/%.pb-c.c $(BUILD)/proto/%.pb-c.h: proto/%.proto
	@mkdir -p $(BUILD)/proto
	protoc-c --c_out=$(BUILD)/proto --proto_path=proto $<
$(BUILD)/proto/%.pb-c.o: $(BUILD)/proto/%.pb-c.c
	$(CC) $(CSTD) $(OPT) $(INC) -c $< -o $@

$(LIB): $(LIB_OBJ)
	@rm -f $@
	ar rcs $@ $^

$(LIBVOX): $(LIBVOX_OBJ)
	@rm -f $@
	ar rcs $@ $^
$(BUILD)/pic/proto/%.pb-c.o: $(BUILD)/proto/%.pb-c.c
	@mkdir -p $(dir $@)
	$(CC) $(CSTD) $(OPT) -fPIC $(INC) -c $< -o $@
$(BUILD)/pic/%.o: %.c | $(PROTO_C)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) -fPIC $(call modinc,$(firstword $(subst /, ,$*))) -c $< -o $@
# libvox.so.1 (the soname) and libvox.so (what -lvox finds) beside it, as
# make install lays them out.
$(LIBVOX_SO): $(LIBVOX_PIC) libvox/libvox.map
	$(CC) -shared -Wl,-soname,libvox.so.$(LIBVOX_MAJOR) -Wl,--version-script=libvox/libvox.map -Wl,--as-needed \
	  $(LDFLAGS) $(LIBVOX_PIC) -o $@ -lprotobuf-c -lz -lm -lpthread
	ln -sf $(notdir $@) $(BUILD)/libvox.so.$(LIBVOX_MAJOR)
	ln -sf libvox.so.$(LIBVOX_MAJOR) $(BUILD)/libvox.so
# The prefix is the one given to make install (the .pc file is rewritten
# there); the build's copy names the default.
$(BUILD)/libvox.pc: libvox/libvox.pc.in
	sed -e 's|@PREFIX@|$(PREFIX)|' $< >$@

$(BUILD)/vox: $(BUILD)/client/vox.o $(LIB)
	$(CC) $(LDFLAGS) $^ -o $@ $(LDLIBS)

# OpenVDB is C++: client/vdb_out.cc, the shim behind vox export's .vdb, is
# the one C++ source, built with g++ into a module of its own that vox
# opens with dlopen for a .vdb only (client/vdb_out.h says why); the rest
# stays C11 and never links libstdc++ or libopenvdb.
VDB_MOD  := $(BUILD)/vox-vdb.so
VDB_LIBS := -lopenvdb -ltbb -lImath
CXXFLAGS += -std=c++17 -Wall -Wextra -Werror $(VDB_OPT) -fPIC -MMD -MP
$(BUILD)/client/vdb_out.o: client/vdb_out.cc
	@mkdir -p $(dir $@)
	$(CXX) $(CXXFLAGS) -Iclient -Icommon -c $< -o $@
$(VDB_MOD): $(BUILD)/client/vdb_out.o
	$(CXX) -shared $(filter -fsanitize=%,$(OPT)) $^ -o $@ $(VDB_LIBS)
# The export tests' own reader of .vdb files (libopenvdb's reader, not
# vox's writer); no sanitizers: none of it is voxd's code.
# The mesh benchmark's reference: OpenVDB's meshToVolume (bench only).
$(BUILD)/vdb_mesh: bench/vdb_mesh.cc $(LIB)
	$(CXX) -std=c++17 -Wall -Wextra -Werror $(OPT) -Imesh -Ivod -Ioctree -Icommon $< $(LIB) -o $@ $(VDB_LIBS) $(LDLIBS)
$(BUILD)/tests/vdb_dump: tests/integration/vdb_dump.cc
	@mkdir -p $(dir $@)
	$(CXX) -std=c++17 -Wall -Wextra -Werror -O1 $< -o $@ $(VDB_LIBS)
# daemon_oom.sh preloads it into the release voxd: no sanitizers.
$(BUILD)/tests/failmalloc.so: tests/integration/failmalloc.c
	@mkdir -p $(dir $@)
	$(CC) -std=c11 -Wall -Wextra -Werror -O2 -fPIC -shared $< -o $@ -ldl

$(BUILD)/voxd: $(BUILD)/daemon/voxd.o $(LIB)
	$(CC) $(LDFLAGS) $^ -o $@ $(LDLIBS)

# vox_mpi (docs/mpi.md): the files that call MPI (mpi/vox_mpi*.c), built
# with mpicc's flags (asked when used: make deps installs mpicc first);
# MPI's headers as system headers, out of our warnings.
MPI_CFLAGS = $(addprefix -isystem ,$(shell mpicc --showme:incdirs))
MPI_LIBS   = $(shell mpicc --showme:link)
MPI_OBJ   := $(patsubst %.c,$(BUILD)/%.o,$(wildcard mpi/vox_mpi*.c))
$(MPI_OBJ): CFLAGS += $(MPI_CFLAGS)
$(BUILD)/vox_mpi: $(MPI_OBJ) $(LIB)
	$(CC) $(LDFLAGS) $^ -o $@ $(LDLIBS) $(MPI_LIBS)

$(BUILD)/voxbench: bench/voxbench.c $(LIB)
	$(CC) $(CFLAGS) $(INC) $< $(LIB) -o $@ $(LDFLAGS) $(LDLIBS)
# voxdbench starts the voxd beside it: build both.
$(BUILD)/voxdbench: bench/voxdbench.c $(LIB) | $(BUILD)/voxd
	$(CC) $(CFLAGS) $(INC) $< $(LIB) -o $@ $(LDFLAGS) $(LDLIBS)
$(BUILD)/bench_expr: bench/bench_expr.c $(LIB)
	$(CC) $(CFLAGS) $(INC) $< $(LIB) -o $@ $(LDFLAGS) $(LDLIBS)
$(BUILD)/bench_mesh: bench/bench_mesh.c bench/bench_util.h $(LIB)
	$(CC) $(CFLAGS) $(INC) $< $(LIB) -o $@ $(LDFLAGS) $(LDLIBS)
# mesh_vox_bench times the mesh voxelizer's kernels (not part of make bench).
$(BUILD)/mesh_vox_bench: bench/mesh_vox_bench.c tests/unit/mesh_shapes.h $(LIB)
	$(CC) $(CFLAGS) $(INC) -Itests/unit $< $(LIB) -o $@ $(LDFLAGS) $(LDLIBS)
# voxwhole times a whole command (scripts/bench-whole.sh): no library.
$(BUILD)/voxwhole: bench/voxwhole.c bench/bench_util.h
	$(CC) $(CFLAGS) $< -o $@ $(LDFLAGS) -lm
# voxserial measures a command's serial share from outside (scripts/bench-serial.sh).
$(BUILD)/voxserial: bench/voxserial.c bench/bench_util.h
	$(CC) $(CFLAGS) $< -o $@ $(LDFLAGS) -lm -pthread

$(BUILD)/tests/%: tests/unit/%.c $(LIB)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) $(INC) -Itests/unit $< $(LIB) -o $@ $(LDFLAGS) $(LDLIBS) -lcriterion
# test_engine_forge's workers forge entries: every one they publish passes
# through the test's __wrap_worker_entry_end (no hook in the library).
$(BUILD)/tests/test_engine_forge: LDFLAGS += -Wl,--wrap=worker_entry_end
# test_pipeline_alloc and test_mesh_weld fail an allocation of the
# library's on purpose, test_mesh_load a file's mapping.
$(BUILD)/tests/test_pipeline_alloc: LDFLAGS += -Wl,--wrap=calloc,--wrap=malloc
$(BUILD)/tests/test_mesh_weld: LDFLAGS += -Wl,--wrap=malloc
$(BUILD)/tests/test_mesh_load: LDFLAGS += -Wl,--wrap=mmap
# test_vod_alloc, test_parse_alloc, test_mesh_alloc,
# test_pipeline_each_alloc and test_client_alloc fail each allocation of a
# call in turn (tests/unit/alloc_fail.h).
ALLOC_FAIL_WRAP := -Wl,--wrap=malloc,--wrap=calloc,--wrap=realloc,--wrap=aligned_alloc,--wrap=free
$(BUILD)/tests/test_vod_alloc: LDFLAGS += $(ALLOC_FAIL_WRAP)
$(BUILD)/tests/test_parse_alloc: LDFLAGS += $(ALLOC_FAIL_WRAP)
$(BUILD)/tests/test_mesh_alloc: LDFLAGS += $(ALLOC_FAIL_WRAP)
$(BUILD)/tests/test_pipeline_each_alloc: LDFLAGS += $(ALLOC_FAIL_WRAP)
$(BUILD)/tests/test_client_alloc: LDFLAGS += $(ALLOC_FAIL_WRAP)

deps:
	@scripts/deps.sh

# The test build: sanitizers on; the runner prints the one summary line.
# The builds take every CPU (JOBS): on CI's 2 cores a serial build was a
# sixth of the run.
JOBS ?= $(shell nproc)
test: deps
	@$(MAKE) --no-print-directory -j$(JOBS) V=asan test-build
	@$(MAKE) --no-print-directory -j$(JOBS) V=release all bench-build
	@scripts/run-tests.sh build/asan

test-build: all $(UNIT_BIN) $(BUILD)/tests/vdb_dump $(BUILD)/tests/failmalloc.so fuzz-build-corpus

# Fuzz harnesses: libFuzzer binaries (clang), and plain drivers that replay the
# seed corpus under the sanitizers for `make test`.
FUZZ_CC := clang
FUZZ_LIB_OBJ := $(LIB_SRC:%.c=build/fuzz/%.o) $(PROTO:proto/%.proto=build/fuzz/proto/%.pb-c.o)
build/fuzz/proto/%.pb-c.c: proto/%.proto
	@mkdir -p build/fuzz/proto
	protoc-c --c_out=build/fuzz/proto --proto_path=proto $<
build/fuzz/proto/%.pb-c.o: build/fuzz/proto/%.pb-c.c
	$(FUZZ_CC) $(CSTD) -O1 -g -Ibuild/fuzz/proto -fsanitize=fuzzer-no-link,address,undefined -c $< -o $@
build/fuzz/%.o: %.c | $(PROTO:proto/%.proto=build/fuzz/proto/%.pb-c.c)
	@mkdir -p $(dir $@)
	$(FUZZ_CC) $(CSTD) -O1 -g $(INC:$(BUILD)/proto=build/fuzz/proto) $(PKG_CFLAGS) -fsanitize=fuzzer-no-link,address,undefined -c $< -o $@
build/fuzz/%: tests/fuzz/%.c $(FUZZ_LIB_OBJ)
	$(FUZZ_CC) $(CSTD) -O1 -g $(INC:$(BUILD)/proto=build/fuzz/proto) $(PKG_CFLAGS) -fsanitize=fuzzer,address,undefined $^ -o $@ $(PKG_LIBS) -lm -lpthread -lrt
$(BUILD)/fuzz-replay/%: tests/fuzz/%.c tests/fuzz/replay_main.c $(LIB)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) $(INC) $^ -o $@ $(LDFLAGS) $(LDLIBS)
.PHONY: fuzz-build-corpus
fuzz-build-corpus: $(FUZZ_SRC:tests/fuzz/%.c=$(BUILD)/fuzz-replay/%)
FUZZ_SECONDS ?= 60
fuzz: $(FUZZ_SRC:tests/fuzz/%.c=build/fuzz/%)
	@for f in $^; do n=$$(basename $$f); mkdir -p build/fuzz/corpus/$$n; \
	  echo "== $$n ($(FUZZ_SECONDS) s)"; \
	  $$f -max_total_time=$(FUZZ_SECONDS) -max_len=65536 build/fuzz/corpus/$$n tests/fuzz/corpus/$$n || exit 1; done

demo: deps all
	@scripts/demo.sh $(BUILD)

# Every benchmark program; make test builds them too, so none rots unbuilt.
BENCH_BIN := $(addprefix $(BUILD)/,voxbench voxdbench bench_expr voxwhole bench_mesh vdb_mesh voxserial mesh_vox_bench)
bench-build: $(BENCH_BIN)

bench: deps all $(BENCH_BIN)
	@scripts/bench.sh $(BUILD)

# vox_mpi against vox voxelize, the whole command (docs/mpi.md).
bench-mpi: all $(BUILD)/voxwhole
	@scripts/bench-mpi.sh $(BUILD)

# The mesh loaders on the Stanford dragon and bunny ($VOXD_MESH_MODELS, or npm),
# then the whole vox voxelize --mesh command on them and on icospheres.
bench-mesh: all $(BUILD)/bench_mesh $(BUILD)/voxwhole $(BUILD)/voxbench $(BUILD)/vdb_mesh
	@scripts/bench-mesh.sh $(BUILD)

# Volume CSG jobs: the vox csg command (scripts/bench-csg.sh, also run by make bench).
bench-csg: all $(BUILD)/voxwhole
	@scripts/bench-csg.sh $(BUILD)

# Every kind of job from 1 to N workers (scripts/bench-scale.sh, also run by make bench).
bench-scale: all $(BUILD)/voxwhole $(BUILD)/bench_mesh $(BUILD)/voxserial
	@scripts/bench-scale.sh $(BUILD)

# The serial share of six jobs, from outside (scripts/bench-serial.sh, also run by make bench).
bench-serial: all $(BUILD)/voxserial
	@scripts/bench-serial.sh $(BUILD)

# The whole vox voxelize command against commit BASE, in one run.
BASE ?= HEAD~1
bench-compare: deps all
	@scripts/bench-compare.sh $(BASE) $(BUILD)

clean:
	rm -rf build

-include $(LIB_OBJ:.o=.d) $(LIBVOX_PIC:.o=.d) $(BUILD)/client/vox.d $(BUILD)/daemon/voxd.d $(MPI_OBJ:.o=.d) $(BUILD)/client/vdb_out.d
# the unit tests' headers too (tests/unit/*.h): a fixture changed rebuilds its suites
-include $(UNIT_BIN:=.d)

# ---------------------------------------------------------------- install
# make install [PREFIX=/usr/local] [DESTDIR=]: vox and vox_mpi in PREFIX/bin; voxd, a
# system daemon, in PREFIX/sbin; the manual pages vox(1) and voxd(8); the
# systemd unit in PREFIX/lib/systemd/system with its paths set to the
# install's; the documentation in PREFIX/share/doc/voxd; libvox (vox.h,
# libvox.a, libvox.so.1 with its links, libvox.pc); the Python reader voxd
# in PYTHONDIR, a directory of the system python3's path (Debian's layout:
# lib/python3/dist-packages under /usr, lib/python3.X/dist-packages under
# any other prefix); vox's bash completion in BASHCOMPDIR; and the commented
# configuration in SYSCONFDIR/voxd/voxd.conf, never over an existing one.
# SYSCONFDIR is /etc whatever the prefix: it is where voxd and vox look for
# the configuration by default.  make uninstall removes all of it, the
# configuration only while it is still the one shipped (an edited one stays).
BINDIR     ?= $(PREFIX)/bin
SBINDIR    ?= $(PREFIX)/sbin
MANDIR     ?= $(PREFIX)/share/man
DOCDIR     ?= $(PREFIX)/share/doc/voxd
UNITDIR    ?= $(PREFIX)/lib/systemd/system
SYSCONFDIR ?= /etc
INSTALL    ?= install
PYTHON     ?= $(firstword $(wildcard /usr/bin/python3) python3)
PYTHONDIR  ?= $(if $(filter /usr,$(PREFIX)),$(PREFIX)/lib/python3/dist-packages,$(PREFIX)/lib/python$(shell \
                $(PYTHON) -c 'import sys; print("%d.%d" % sys.version_info[:2])')/dist-packages)
BASHCOMPDIR ?= $(PREFIX)/share/bash-completion/completions
PY_FILES   := $(wildcard python/voxd/*.py)
DOC_FILES  := $(wildcard docs/*.md docs/*.png)
CONF_DEST   = $(DESTDIR)$(SYSCONFDIR)/voxd/voxd.conf

.PHONY: install uninstall
install: all
	$(INSTALL) -d "$(DESTDIR)$(BINDIR)" "$(DESTDIR)$(SBINDIR)" "$(DESTDIR)$(MANDIR)/man1" \
	  "$(DESTDIR)$(MANDIR)/man8" "$(DESTDIR)$(UNITDIR)" "$(DESTDIR)$(DOCDIR)/docs" \
	  "$(DESTDIR)$(SYSCONFDIR)/voxd"
	$(INSTALL) -m 755 $(BUILD)/vox "$(DESTDIR)$(BINDIR)/vox"
	$(INSTALL) -m 755 $(BUILD)/vox_mpi "$(DESTDIR)$(BINDIR)/vox_mpi"
	$(INSTALL) -d "$(DESTDIR)$(PREFIX)/lib/voxd"
	$(INSTALL) -m 644 $(VDB_MOD) "$(DESTDIR)$(PREFIX)/lib/voxd/vox-vdb.so"
	$(INSTALL) -m 755 $(BUILD)/voxd "$(DESTDIR)$(SBINDIR)/voxd"
	$(INSTALL) -m 644 docs/man/vox.1 "$(DESTDIR)$(MANDIR)/man1/vox.1"
	$(INSTALL) -m 644 docs/man/voxd.8 "$(DESTDIR)$(MANDIR)/man8/voxd.8"
	sed -e 's|/usr/local/sbin/voxd|$(SBINDIR)/voxd|g' \
	    -e 's|/etc/voxd/voxd.conf|$(SYSCONFDIR)/voxd/voxd.conf|g' \
	    -e 's|/usr/local/share/doc/voxd|$(DOCDIR)|g' config/voxd.service >$(BUILD)/voxd.service
	$(INSTALL) -m 644 $(BUILD)/voxd.service "$(DESTDIR)$(UNITDIR)/voxd.service"
	$(INSTALL) -m 644 README.md "$(DESTDIR)$(DOCDIR)/README.md"
	$(INSTALL) -m 644 $(DOC_FILES) "$(DESTDIR)$(DOCDIR)/docs/"
	$(INSTALL) -d "$(DESTDIR)$(PREFIX)/lib/pkgconfig" "$(DESTDIR)$(PREFIX)/include"
	$(INSTALL) -m 644 $(LIBVOX) "$(DESTDIR)$(PREFIX)/lib/libvox.a"
	$(INSTALL) -m 755 $(LIBVOX_SO) "$(DESTDIR)$(PREFIX)/lib/$(notdir $(LIBVOX_SO))"
	ln -sf $(notdir $(LIBVOX_SO)) "$(DESTDIR)$(PREFIX)/lib/libvox.so.$(LIBVOX_MAJOR)"
	ln -sf libvox.so.$(LIBVOX_MAJOR) "$(DESTDIR)$(PREFIX)/lib/libvox.so"
	$(INSTALL) -d "$(DESTDIR)$(PYTHONDIR)/voxd" "$(DESTDIR)$(BASHCOMPDIR)"
	$(INSTALL) -m 644 $(PY_FILES) "$(DESTDIR)$(PYTHONDIR)/voxd/"
	$(INSTALL) -m 644 config/vox.bash-completion "$(DESTDIR)$(BASHCOMPDIR)/vox"
	$(INSTALL) -m 644 libvox/vox.h "$(DESTDIR)$(PREFIX)/include/vox.h"
	$(INSTALL) -m 644 proto/vox_limits.h "$(DESTDIR)$(PREFIX)/include/vox_limits.h"
	sed -e 's|@PREFIX@|$(PREFIX)|' libvox/libvox.pc.in >"$(DESTDIR)$(PREFIX)/lib/pkgconfig/libvox.pc"
	@if [ -e "$(CONF_DEST)" ]; then \
	  echo "install: keeping the existing $(CONF_DEST) (the shipped one is config/voxd.conf)"; \
	else echo "$(INSTALL) -m 644 config/voxd.conf $(CONF_DEST)"; \
	  $(INSTALL) -m 644 config/voxd.conf "$(CONF_DEST)"; fi
	@if [ -z "$(DESTDIR)" ] && command -v ldconfig >/dev/null; then echo ldconfig; ldconfig; fi

uninstall:
	rm -f "$(DESTDIR)$(BINDIR)/vox" "$(DESTDIR)$(BINDIR)/vox_mpi" "$(DESTDIR)$(SBINDIR)/voxd" \
	  "$(DESTDIR)$(PREFIX)/lib/voxd/vox-vdb.so" \
	  "$(DESTDIR)$(MANDIR)/man1/vox.1" "$(DESTDIR)$(MANDIR)/man8/voxd.8" \
	  "$(DESTDIR)$(UNITDIR)/voxd.service" "$(DESTDIR)$(DOCDIR)/README.md" \
	  "$(DESTDIR)$(PREFIX)/lib/libvox.a" "$(DESTDIR)$(PREFIX)/include/vox.h" \
	  "$(DESTDIR)$(PREFIX)/lib/$(notdir $(LIBVOX_SO))" "$(DESTDIR)$(PREFIX)/lib/libvox.so.$(LIBVOX_MAJOR)" \
	  "$(DESTDIR)$(PREFIX)/lib/libvox.so" "$(DESTDIR)$(BASHCOMPDIR)/vox" \
	  $(PY_FILES:python/%="$(DESTDIR)$(PYTHONDIR)/%") \
	  "$(DESTDIR)$(PREFIX)/include/vox_limits.h" \
	  "$(DESTDIR)$(PREFIX)/lib/pkgconfig/libvox.pc" \
	  $(DOC_FILES:docs/%="$(DESTDIR)$(DOCDIR)/docs/%")
	rm -rf "$(DESTDIR)$(PYTHONDIR)/voxd/__pycache__"
	rmdir "$(DESTDIR)$(DOCDIR)/docs" "$(DESTDIR)$(DOCDIR)" "$(DESTDIR)$(PREFIX)/lib/voxd" \
	  "$(DESTDIR)$(PYTHONDIR)/voxd" 2>/dev/null || true
	@if cmp -s config/voxd.conf "$(CONF_DEST)"; then \
	  echo "rm -f $(CONF_DEST)"; rm -f "$(CONF_DEST)"; \
	  rmdir "$(DESTDIR)$(SYSCONFDIR)/voxd" 2>/dev/null || true; \
	elif [ -e "$(CONF_DEST)" ]; then \
	  echo "uninstall: keeping $(CONF_DEST): it differs from the shipped config/voxd.conf"; fi
