# Two commands on a fresh clone: `make demo` and `make test`. Both set up .venv/ first (once).
VENV   := .venv
PY     := $(VENV)/bin/python
BOW    := $(VENV)/bin/bowsynth
STAMP  := $(VENV)/.installed-stamp
OUTDIR := out

.PHONY: setup demo test models tables docs docs-models bench bench-docs bench-quick clean chromium jackd core

$(STAMP): pyproject.toml CMakeLists.txt $(wildcard src/core/*)
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# the CPU build of torch lies on this machine; a bare `torch` would pull a multi-GB CUDA build
	$(PY) -m pip install -q torch==2.13.0
	# builds the compiled core (src/core) with scikit-build-core: needs g++; CMake and nanobind come from PyPI, into
	# the venv and used from there (no build isolation), so that the wheel test (tests/test_reliability.py) builds
	# with the same tools into the same build directory and recompiles nothing (in an isolated env, another nanobind
	# and CMake: the core compiled again, 60 s of the suite)
	$(PY) -m pip install -q 'scikit-build-core>=0.10' 'nanobind>=2.0' cmake ninja
	$(PY) -m pip install -q --no-build-isolation -e '.[test,cluster]'
	touch $(STAMP)

setup: $(STAMP) chromium jackd

demo: $(STAMP)
	mkdir -p $(OUTDIR)
	$(BOW) render --preset paper-fb100 $(OUTDIR)/demo.wav
	$(BOW) compare $(OUTDIR)/demo.wav --plot $(OUTDIR)/demo.png --report $(OUTDIR)/demo-report.html
	$(BOW) render --preset scratch-g2 $(OUTDIR)/scratch-g2.wav
	$(BOW) compare $(OUTDIR)/scratch-g2.wav
	$(BOW) render --preset violin-a4 $(OUTDIR)/violin-a4.flac
	$(BOW) score --score examples/melody.mid --mix $(OUTDIR)/melody.wav --stems $(OUTDIR)/melody.stems --force
	$(BOW) render --method fdm --fb 50@0,300@1,50@2 --pitch D4 -d 2.5 $(OUTDIR)/swell-fdm.wav
	$(BOW) render --fb 50@0,200@2 --vb 0.15 -d 2 $(OUTDIR)/crescendo.wav
	$(BOW) compare $(OUTDIR)/crescendo.wav

# the suite on every core (pytest-xdist): its bulk is the held bows' rows, each a model chosen by listening from a cold
# cache, seconds of single-threaded work apiece; idle on 2 cores 1142 tests took 11m17s, 1151 on two workers 8m55s
test: $(STAMP) chromium jackd
	$(PY) -m pytest -n auto

# The shipped operators: each is trained by its recipe beside it (models/NAME.toml: the flags of
# `bowsynth train`), on a 2-core CPU at most 15 minutes for a point model (40 for paper-fb1000-half and -knee, the
# paper's stick-slip scene on half-period windows) and 45 for a range model. Only what is missing, unreadable or stale
# against its recipe is trained (`train --update`); an interrupted run continues from its checkpoint, so `make models`
# can be stopped and run again. A recipe with a `from` key refines another model (`train --from`) and is built after
# that model's recipe (bowsynth.training.recipe.build_order); models/stages holds models a render never picks,
# kept to rebuild the ones refined from them. The catalogue, each model's box and validation: `bowsynth models`,
# docs/models.md.
RECIPES := $(wildcard models/stages/*.toml) $(wildcard models/*.toml)
models: $(STAMP)
	order=$$($(PY) -m bowsynth.training.recipe $(RECIPES)) || exit 1; \
	for r in $$order; do $(BOW) train --config $$r --update || exit 1; done
	$(PY) -m bowsynth.training.manifest
	$(PY) -m bowsynth.music.model_ratio

# The tables a render reads instead of running the reference: the physics' sounding ratio over the bow plane, solved
# on a grid (models/tables/physics-ratio.npz; ~2 min on two cores; `check` measures it off its grid), and
# the shipped models' own ratios at every MIDI velocity's bow (own-ratios.json, ~2 s: `play` starts without them).
tables: $(STAMP)
	$(PY) -m bowsynth.music.ratio_map build
	$(PY) -m bowsynth.music.ratio_map check --n 80
	$(PY) -m bowsynth.music.model_ratio

# docs/api/: the API reference, built by pdoc from the numpydoc docstrings of these modules (not committed;
# tests/test_docs.py runs their examples and builds the same page from this list)
DOC_MODULES := bowsynth.api bowsynth.scene bowsynth.render bowsynth.music.score bowsynth.music.note bowsynth.live.stream bowsynth.live.budget bowsynth.music.request
docs: $(STAMP)
	$(PY) -m pdoc --docformat numpy -o docs/api $(DOC_MODULES)

# docs/models.md and docs/atlas.png: the shipped catalogue as `bowsynth models` lists it, and its tiling
docs-models: $(STAMP)
	{ echo "# The shipped models"; echo; echo "bowsynth models, as it prints them (make docs-models writes this page):"; \
	  echo "where each plays (its box of F_B / w and v_B), its windows (T the free period), its validation (harmonics dB"; \
	  echo "median / pitch cents worst over its grid, or a point model's NMSE) and its size."; echo; \
	  echo "![The tiling of the bow plane](atlas.png)"; echo; echo '```'; \
	  COLUMNS=120 $(BOW) models --map docs/atlas.png --force | grep -v '^map written'; echo '```'; } > docs/models.md

# The report tests open pages in Debian's chromium, driven by playwright (the test extra) with no browser download.
chromium:
	@command -v chromium >/dev/null || { S=$$([ "$$(id -u)" = 0 ] || echo sudo); $$S apt-get update && $$S apt-get install -y chromium; } || echo "chromium could not be installed: the browser tests will skip"

# `bowsynth play` is a JACK client: libjack and the server (its dummy driver needs no sound card) come with jackd2.
jackd:
	@command -v jackd >/dev/null || { S=$$([ "$$(id -u)" = 0 ] || echo sudo); $$S apt-get update && DEBIAN_FRONTEND=noninteractive $$S apt-get install -y jackd2; } || echo "jackd2 could not be installed: bowsynth play and its tests will skip"

bench: $(STAMP)
	$(BOW) bench --out docs/bench

# the docs' generated tables (the `<!-- generated: ... -->` blocks of docs/*.md), each rewritten with what its
# command prints now (~40 minutes here)
bench-docs: $(STAMP)
	$(PY) benchmarks/refresh_docs.py

bench-quick: $(STAMP)
	$(BOW) bench --quick

# The compiled core alone, into bowsynth/ (for a source tree run with PYTHONPATH and another venv's python: PY=...)
core:
	$(PY) -m pip install -q 'nanobind>=2.0' cmake ninja
	$(dir $(PY))cmake -S . -B build/core -G Ninja -DCMAKE_MAKE_PROGRAM=$(abspath $(dir $(PY))ninja) \
	    -DCMAKE_BUILD_TYPE=Release -DPython_EXECUTABLE=$(abspath $(PY))
	$(dir $(PY))cmake --build build/core -j2

clean:
	rm -rf $(OUTDIR) .pytest_cache
