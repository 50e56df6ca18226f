# Two commands on a fresh clone: `make demo` and `make test`. Both set up .venv/ first (once).
VENV   := .venv
PY     := $(VENV)/bin/python
BOW    := $(VENV)/bin/bowsynth
STAMP  := $(VENV)/.installed-stamp
OUTDIR := out

.PHONY: setup demo test models tables docs-models bench bench-quick clean chromium jackd core

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

# The shipped operators: each is trained by its recipe beside it (bowsynth/models/NAME.toml: the flags of
# `bowsynth train`), on a 2-core CPU at most 15 minutes for each point model (40 for paper-fb1000-half and -knee, the
# paper's stick-slip scene on half-period windows) and 45 for a range model. Only what is missing, unreadable or stale
# against its recipe is trained (`train --update`); an interrupted run continues from its checkpoint, so `make
# models` can be stopped and run again. A wide stick-slip range failed its validation and is
# not shipped; velocity-loud is a small stick-slip tile where loud MIDI notes go, loud-stops their bow stops, loud-mid
# the soft / stick-slip border at moderate bow speeds, loud-seam the light fast bows between loud-mid and fast-bow;
# stick-mid, -low, -slow, -high, -stops, -heavy, -creep, -top, floor-long and creep-mid: stick-slip tiles on
# quarter-period windows; soft-top and soft-high: the soft bow's top
# forces; soft-fast its fastest bows, fast-long the fastest of them; corner-long the light fast corner (floor-long,
# creep-mid, fast-long and corner-long learnt from renders of 6, 6, 6 and 16 s: their notes take seconds to settle);
# stick-halt the heavy bow stops (stick-halt-high those above F_B / w 1.72, halt-edge the damped bows at the space's
# edge, F_B / w 1.9-2.02 x v_B 0-0.08, halt-floor the heavy bows held just below vb_stop, halt-band, high-band and
# edge-band those held just above it, stops-band stick-stops' held just above it, failed by ear and played only where
# measured truer: a rerun of halt-band's or stops-band's recipe need not reproduce its shipped file, as each says)
# and stick-gap the fast bows between stick-fast and stick-high, refined in stages (bowsynth/models/stages: models
# a render never picks, kept to rebuild them), gap-top stick-gap refined on its light fast corner, stick-slow refined
# on a GPU from its session-19 self (stages/stick-slow-1); halt-bottom, bottom-band, upper-band, low-band, floor-band,
# edge-floor, light-floor, seam-floor, mid-narrow, seam-low, seam-mid, edge-narrow, light-narrow, seam-bottom,
# seam-light, edge-low, edge-top and edge-sill refine the band just above vb_stop in ever narrower boxes (halt-bottom,
# low-band, floor-band, edge-floor, light-floor, mid-narrow, seam-mid, edge-narrow, seam-bottom, seam-light, edge-low,
# edge-top and edge-sill failed by ear and play only where measured truer; seam-bottom, seam-light, edge-low, edge-top
# and edge-sill trained without the derivative term); seam-roll, edge-roll, seam-edge, seam-corner, mid-edge, mid-high,
# mid-corner, mid-core, seam-stripe, stripe-edge, stripe-top, high-sill, band-stripe, mid-sill, halt-ledge,
# floor-ledge, light-ledge, under-ledge, deep-ledge, stops-ledge (failed by ear), floor-high and floor-low are
# seam-light, edge-top, seam-low, halt-bottom, mid-edge, halt-band, high-band, floor-band, bottom-band and stops-band
# refined with the rollout term; rim-top stick-slip's top rim; fast-onset stick-fast refined with the rollout term on
# its fast heavy bows, where its notes spoke a cycle late (BENCHMARKS.md).
# A recipe with a `from` key refines another model (`train --from`): it is built after the recipe of that model
# (bowsynth.training.recipe.build_order).
RECIPES := $(wildcard bowsynth/models/stages/*.toml) $(wildcard bowsynth/models/*.toml)
models: $(STAMP)
	order=$$($(PY) -m bowsynth.training.recipe $(RECIPES)) || exit 1; \
	for r in $$order; do $(BOW) train --config $$r --update || exit 1; done
	$(PY) -m bowsynth.training.manifest
	$(PY) -m bowsynth.music.model_ratio

# The tables a render reads instead of running the reference: the physics' sounding ratio over the bow plane, solved
# on a grid (bowsynth/models/tables/physics-ratio.npz; ~2 min on two cores; `check` measures it off its grid), and
# the shipped models' own ratios at every MIDI velocity's bow (own-ratios.json, ~2 s: `play` starts without them).
tables: $(STAMP)
	$(PY) -m bowsynth.music.ratio_map build
	$(PY) -m bowsynth.music.ratio_map check --n 80
	$(PY) -m bowsynth.music.model_ratio

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
