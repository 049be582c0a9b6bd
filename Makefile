# Two commands set everything up on a fresh machine: `make demo` and `make test`.
# Both create .venv, install the pinned wheels and libosmesa6 when they are missing.
SHELL := /bin/bash
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
export PYOPENGL_PLATFORM ?= osmesa
# ROS traffic of tests and the demo stays on this machine (see config/fastdds_loopback.xml;
# test/conftest.py names it to Fast DDS 2, Jazzy's, as FASTRTPS_DEFAULT_PROFILES_FILE).
export FASTDDS_DEFAULT_PROFILES_FILE ?= $(CURDIR)/config/fastdds_loopback.xml
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export RMW_IMPLEMENTATION ?= rmw_fastrtps_cpp
# A private network namespace with only loopback, where the machine allows one (root).
ISOLATED := $(shell unshare -n true 2>/dev/null && echo "unshare -n sh -c 'ip link set lo up && exec \"\$$0\" \"\$$@\"'")

.PHONY: setup demo test fuzz sweep flood test-distro test-jazzy lint bench bench-cycles bench-stations bench-pt cycles-setup bench-detector bench-render bench-node bench-node-load bench-reuse bench-node-compare bench-transport bench-node-outputs profile-node bench-generate eval-bench ablate-bench synth-demo synth-bench synth-bench-val bench-dark bench-objects bench-sky bench-tracker param-study station-model clean

setup: $(STAMP)

$(STAMP): requirements.txt requirements-dev.txt requirements-torch.txt setup.py
	@if ! ldconfig -p 2>/dev/null | grep -q libOSMesa.so; then \
	  echo "installing libosmesa6 (headless OpenGL)"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libosmesa6 >/dev/null; \
	fi
	@test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check -r requirements-dev.txt
	$(PY) -m pip install -q --disable-pip-version-check --no-deps -e .
	@touch $@

demo: $(STAMP)
	$(ISOLATED) $(PY) -m allo_mrad_ros.demo

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

# Each stage of `make test` runs its tests in TEST_WORKERS processes (pytest-xdist), each with
# a DDS domain of its own (test/conftest.py); TEST_WORKERS=0 runs them in one process.
TEST_WORKERS ?= 2
PARALLEL := $(if $(filter 0,$(TEST_WORKERS)),,-n $(TEST_WORKERS))

test: lint
	$(ISOLATED) $(PY) -m pytest -q --timeout=600 $(PARALLEL)
	$(MAKE) test-distro
	$(MAKE) test-jazzy

# Bad-input fuzzing: several hundred generated cases per property (hypothesis) over image
# headers, camera_info, poses, Sun vectors and sequence rows; prints the count per verdict.
# `make test` runs the same properties with a few examples each.
fuzz: $(STAMP)
	ALLO_FUZZ=1 $(PY) -m pytest -q -p no:cacheprovider --timeout=300 test/fuzz

# The bad-input sweep: ~190 kinds of bad input against the node (over DDS on
# loopback), allo-bag and allo-synth (real read-only mounts, tmpfs full disks, signals);
# prints each case's verdict and the count per verdict, writes reports/sweep/sweep.{json,md},
# exits 1 if any case is not clean. `make test` runs its quick cases (test/sweep).
sweep: $(STAMP)
	$(ISOLATED) $(PY) test/sweep/sweep.py --out reports/sweep

# The node under a 1080p flood at 30 Hz for 10 minutes: alive, RSS growth after the first
# minute, /diagnostics levels while flooding and seconds to STALE after the last image.
flood: $(STAMP)
	$(ISOLATED) $(PY) -m benchmarks.flood --minutes 10 --rate 30 --out reports/flood.json

# The distro route's Python side, without a ROS install: Python 3.10 and the NumPy 1.21 / SciPy
# 1.8 / OpenCV 4.5 that Ubuntu 22.04 (Humble) ships, plus requirements-distro*.txt, then every
# test that needs no rclpy (docs/distro.md). Skipped where no python3.10 exists.
DISTRO_PYTHON ?= $(firstword $(foreach c,python3.10 $(wildcard $(HOME)/.pyenv/versions/3.10*/bin/python3.10) /usr/bin/python3.10,$(shell $(c) -c 'import sys; print(sys.executable)' 2>/dev/null)))
DISTRO_VENV := .venv-distro
DISTRO_STAMP := $(DISTRO_VENV)/.installed
test-distro:
	@if [ -z "$(DISTRO_PYTHON)" ]; then echo "test-distro: no python3.10 here, skipped"; \
	else $(MAKE) --no-print-directory $(DISTRO_STAMP) && \
	  $(ISOLATED) $(DISTRO_VENV)/bin/python -m pytest -q --timeout=600 -p no:cacheprovider $(PARALLEL); fi

$(DISTRO_STAMP): test/data/humble_apt_stand_ins.txt requirements-distro.txt requirements-distro-nodeps.txt setup.py
	@test -x $(DISTRO_VENV)/bin/python || $(DISTRO_PYTHON) -m venv $(DISTRO_VENV)
	$(DISTRO_VENV)/bin/python -m pip install -q --disable-pip-version-check \
	  -r test/data/humble_apt_stand_ins.txt -r requirements-distro.txt
	$(DISTRO_VENV)/bin/python -m pip install -q --disable-pip-version-check --no-deps \
	  --ignore-requires-python -r requirements-distro-nodeps.txt
	$(DISTRO_VENV)/bin/python -m pip install -q --disable-pip-version-check --no-deps -e .
	@touch $@

# ROS 2 Jazzy, on its own wheels from PyPI (rclpy 7.1, Fast DDS 2.14): Python 3.12 and the
# NumPy 1.26.4 / SciPy 1.11.4 / OpenCV 4.6 that Ubuntu 24.04 ships (requirements-jazzy.txt,
# with requirements-distro*.txt), then every test that touches ROS (ALLO_TESTS=ros,
# test/conftest.py). Skipped where no python3.12 exists.
JAZZY_PYTHON ?= $(firstword $(foreach c,python3.12 $(wildcard $(HOME)/.pyenv/versions/3.12*/bin/python3.12) /usr/bin/python3.12,$(shell $(c) -c 'import sys; print(sys.executable)' 2>/dev/null)))
JAZZY_VENV := .venv-jazzy
JAZZY_STAMP := $(JAZZY_VENV)/.installed
test-jazzy:
	@if [ -z "$(JAZZY_PYTHON)" ]; then echo "test-jazzy: no python3.12 here, skipped"; \
	else $(MAKE) --no-print-directory $(JAZZY_STAMP) && \
	  ALLO_TESTS=ros $(ISOLATED) $(JAZZY_VENV)/bin/python -m pytest -q --timeout=600 -p no:cacheprovider $(PARALLEL); fi

$(JAZZY_STAMP): requirements-jazzy.txt requirements-distro.txt requirements-distro-nodeps.txt setup.py
	@test -x $(JAZZY_VENV)/bin/python || $(JAZZY_PYTHON) -m venv $(JAZZY_VENV)
	$(JAZZY_VENV)/bin/python -m pip install -q --disable-pip-version-check -r requirements-jazzy.txt
	$(JAZZY_VENV)/bin/python -m pip install -q --disable-pip-version-check --no-deps \
	  --ignore-requires-python -r requirements-distro-nodeps.txt
	$(JAZZY_VENV)/bin/python -m pip install -q --disable-pip-version-check --no-deps -e .
	@touch $@

bench-detector: $(STAMP)
	$(PY) -m benchmarks.detector --out reports/bench_detector.json

bench-render: $(STAMP)
	$(PY) -m benchmarks.render --out reports/bench_render.json

bench-node: $(STAMP)
	$(ISOLATED) $(PY) -m benchmarks.node --frames 1000 --out reports/bench_node.json
	$(ISOLATED) $(PY) -m benchmarks.node --compare-outputs --out reports/bench_node_outputs.json

# The node's latency under a busy CPU: LOAD busy loops beside it (one per core) for 2 minutes
# at 1080p30, the feed and recorder raised above them; per-stage figures from /diagnostics.
LOAD ?= 2
bench-node-load: $(STAMP)
	$(ISOLATED) $(PY) -m benchmarks.node --load $(LOAD) --modes 1080p30 --trajectory moving \
	  --seconds 120 --out reports/bench_node_load.json

# Accuracy cost of reference reuse on moving-arm trajectories (renders per frame, P.AP).
bench-reuse: $(STAMP)
	$(PY) -m benchmarks.reuse --out reports/bench_reuse.json

# Both workers in one run: per camera mode the one-thread node, then the pipelined one.
bench-node-compare: $(STAMP)
	$(ISOLATED) $(PY) -m benchmarks.node --frames 1000 --compare-serial --out reports/bench_node_compare.json

# One frame of the node's path under cProfile (decode, render, detect, outputs), 1080p.
profile-node: $(STAMP)
	$(ISOLATED) $(PY) -m benchmarks.node_profile --frames 20 --out reports/profile_node.json

# Full-HD frames into Python processes: a publisher, the node and a plain subscriber at
# 1080p30 and 720p60, 30 s each, under Fast DDS's defaults, LARGE_DATA, the deployment
# profile (config/fastdds_large_images.xml; best-effort and reliable) and compressed input;
# delivered frames, latency, CPU of both sides (docs/distro.md). In a private network
# namespace: the defaults stay on this machine.
TRANSPORT_SECONDS ?= 30
# First its short run (2 s per setting, too long for `make test`).
bench-transport: $(STAMP)
	$(ISOLATED) env ALLO_TRANSPORT_SMOKE=1 $(PY) -m pytest -q -p no:cacheprovider --timeout=300 \
	  test/benchmarks/test_transport.py
	$(ISOLATED) $(PY) -m benchmarks.transport --duration $(TRANSPORT_SECONDS) --out reports/bench_transport.json

# Only the output comparison of bench-node: CPU per frame of ~/mask alone, plus each output, every output.
bench-node-outputs: $(STAMP)
	$(ISOLATED) $(PY) -m benchmarks.node --compare-outputs --out reports/bench_node_outputs.json

# Speed against error: defaults chosen on data/bench_val, reported on data/bench's test split
# (both generated first if missing: 510 + 330 frames, 37 + 22 min with 2 jobs at load 8-12
# on 2 cores; not measured idle).
bench: $(STAMP) data/bench/frames.csv data/bench_val/frames.csv
	$(PY) -m benchmarks.tradeoff --sequence data/bench --validation data/bench_val --out reports

data/bench/frames.csv:
	$(MAKE) synth-bench

data/bench_val/frames.csv:
	$(MAKE) synth-bench-val

synth-bench: $(STAMP)
	$(PY) -m allo_mrad_ros.synth.entry generate --preset bench --seed 0 --out data/bench --overwrite --jobs 2

# The selection split of `make bench`: another seed, so it shares no frame plan with the test.
synth-bench-val: $(STAMP)
	$(PY) -m allo_mrad_ros.synth.entry generate --preset bench-val --seed 1 --out data/bench_val --overwrite --jobs 2

synth-demo: $(STAMP)
	$(PY) -m allo_mrad_ros.synth.entry generate --preset demo --seed 0 --out data/demo/sequence --overwrite

# Path-traced queries: the bench-cycles preset (test 16 normal + 32 anomalous at
# 640x360) with queries rendered by Blender Cycles, references rasterised by the evaluator,
# and its twin (the same plan with rasterised queries), each generated once (delete the
# folder to regenerate); checks Cycles' silhouettes against the masks, evaluates both and
# sorts the pixels that score falsely by kind (edges, space, dark/mid/bright station).
# Installs the optional bpy (requirements-cycles.txt, ~375 MB) into the venv first;
# `make test` and `make demo` never need it.
CYCLES_STAMP := $(VENV)/.cycles-installed
cycles-setup: $(CYCLES_STAMP)

$(CYCLES_STAMP): requirements-cycles.txt $(STAMP)
	$(PY) -m pip install -q --disable-pip-version-check --no-deps -r requirements-cycles.txt
	@touch $@

# The multi-station path-traced bench: three station models per split, none shared between
# validation (the package's station, Skylab, TDRS) and test (Hubble, Apollo-Soyuz, Mir);
# queries path-traced by Cycles under AgX, Filmic and Standard view transforms, -1..+1.5 EV,
# JPEG; defaults are chosen on val, reported on test. The public models are not in git: put
# NASA-3D-Resources' skylab.glb, tdrs.glb, hubble_space_telescope.glb, apollo_soyuz.glb and
# mir.glb into $(STATIONS_SRC) first (docs/evaluation.md, "Multi-station bench").
STATIONS_SRC ?= data/stations
STATION_SETTINGS ?= default,no_transfer,transfer_reference,no_transfer_affine_map,PAD,RXD
bench-stations: $(CYCLES_STAMP)
	$(PY) -m benchmarks.stations prepare $(STATIONS_SRC) --out data/stations_prepared
	$(PY) -m benchmarks.stations generate data/stations_prepared --out data/bench_stations
	$(PY) -m benchmarks.stations_bench data/bench_stations --split val \
	  --settings $(STATION_SETTINGS) --out reports/bench_stations_val.json
	$(PY) -m benchmarks.stations_bench data/bench_stations --split test \
	  --settings $(STATION_SETTINGS) --recall --out reports/bench_stations_test.json

# The extended path-traced bench: queries that share neither the reference's materials nor
# its lamps (roughness and specular strength moved per material, Earth-shine, an area light
# for the spot lamp), AgX/Filmic/Standard and a camera response of our own, and the hard
# object kinds (thin cables, dark objects, small objects, station-coloured ones) reported
# per kind and per station. Stations: the package's and three procedural outposts, two with
# their materials in texture maps; val and test share none (docs/evaluation.md).
PT_SETTINGS ?= default,PAD,RXD
bench-pt: $(CYCLES_STAMP)
	$(PY) -m benchmarks.stations outposts data/stations_pt
	$(PY) -m benchmarks.stations generate data/stations_pt --bench pt --out data/bench_pt
	$(PY) -m benchmarks.stations_bench data/bench_pt --bench pt --split val \
	  --settings $(PT_SETTINGS) --recall --kinds --out reports/bench_pt_val.json
	$(PY) -m benchmarks.stations_bench data/bench_pt --bench pt --split test \
	  --settings $(PT_SETTINGS) --recall --kinds --out reports/bench_pt_test.json

bench-cycles: $(CYCLES_STAMP) data/bench_cycles/frames.csv data/bench_cycles_twin/frames.csv
	$(PY) -m benchmarks.cycles_silhouettes data/bench_cycles --frames 8 --out reports/cycles_silhouettes.json
	$(PY) -m rosbag_tools evaluate data/bench_cycles --out reports/eval_bench_cycles --overwrite --jobs 1
	$(PY) -m rosbag_tools evaluate data/bench_cycles_twin --out reports/eval_bench_cycles_twin --overwrite --jobs 1
	$(PY) -m benchmarks.false_scores data/bench_cycles --out reports/false_scores_cycles.json
	$(PY) -m benchmarks.false_scores data/bench_cycles_twin --out reports/false_scores_cycles_twin.json

data/bench_cycles/frames.csv: | $(CYCLES_STAMP)
	$(PY) -m allo_mrad_ros.synth.entry generate --preset bench-cycles --seed 0 --out data/bench_cycles --overwrite

data/bench_cycles_twin/frames.csv: | $(STAMP)
	$(PY) -m allo_mrad_ros.synth.entry generate --preset bench-cycles --seed 0 --query-renderer pyrender --out data/bench_cycles_twin --overwrite

# Dark glossy objects (the opt-in dark_visor) against dark station parts: the structure cue
# off and on, on the bench-dark validation and test splits (docs/evaluation.md).
DARK_SETTINGS = default,default:structure_weight=0.03,default:structure_weight=0.1
bench-dark: $(STAMP) data/bench_dark/frames.csv
	$(PY) -m benchmarks.stations_bench data/bench_dark --sequence --split val \
	  --settings $(DARK_SETTINGS) --recall --out reports/bench_dark_val.json
	$(PY) -m benchmarks.stations_bench data/bench_dark --sequence --split test \
	  --settings $(DARK_SETTINGS) --recall --compare default,default:structure_weight=0.03 \
	  --out reports/bench_dark_test.json

data/bench_dark/frames.csv: | $(STAMP)
	$(PY) -m allo_mrad_ros.synth.entry generate --preset bench-dark --seed 0 --out data/bench_dark --overwrite

# Objects in the station frame (docs/objects.md): generates data/objects if missing, chooses
# the tracker's parameters on val, reports val and test, and the test split of another station
# with path-traced queries (data/objects_pt, generated with Cycles if missing);
# reports/bench_objects.json.
bench-objects: $(CYCLES_STAMP)
	$(PY) -m benchmarks.objects --out reports/bench_objects.json

# Light in the sky the reference cannot draw (docs/evaluation.md): the Sun's glare and the
# bodies' limbs on the frames with them in view, per value, on the validation sequences (where
# the defaults were chosen), then on the test ones; generates the sequences it needs if
# missing (the path-traced ones with Cycles).
SKY_PT := $(PY) -m allo_mrad_ros.synth.entry generate --preset objects-pt --jobs 2
SKY_VAL := data/objects:val data/bench_val:val data/objects_pt_hub
SKY_TEST := data/objects:test data/bench:test data/objects_pt data/objects_pt_ring
bench-sky: $(CYCLES_STAMP) data/bench/frames.csv data/bench_val/frames.csv
	test -f data/objects/frames.csv || $(PY) -m allo_mrad_ros.synth.entry generate --preset objects --seed 0 --out data/objects --jobs 2
	test -f data/stations_pt/outpost_hub.glb || $(PY) -m benchmarks.stations outposts data/stations_pt
	test -f data/objects_pt_hub/frames.csv || $(SKY_PT) --mesh data/stations_pt/outpost_hub.glb --seed 11 --trajectory-frames 40 --out data/objects_pt_hub
	test -f data/objects_pt/frames.csv || $(SKY_PT) --mesh data/stations_pt/outpost_spine.glb --seed 7 --out data/objects_pt
	test -f data/objects_pt_ring/frames.csv || $(SKY_PT) --mesh data/stations_pt/outpost_ring.glb --seed 9 --out data/objects_pt_ring
	$(PY) -m benchmarks.sky sun_glare $(SKY_VAL) --values 0,1,2,3,4,5,6,8,10,12,16 --out reports/sky_sun_glare_val.json
	$(PY) -m benchmarks.sky sun_glare $(SKY_TEST) --values 0,8 --out reports/sky_sun_glare_test.json
	$(PY) -m benchmarks.sky body_margin $(SKY_VAL) --values 0,0.5,1,1.5,2,3 --out reports/sky_body_margin_val.json
	$(PY) -m benchmarks.sky body_margin $(SKY_TEST) --values 0,1 --out reports/sky_body_margin_test.json

# The object tracker's cost per frame: 20 regions, 50 objects.
bench-tracker: $(STAMP)
	$(PY) -m benchmarks.tracker

eval-bench: $(STAMP) data/bench/frames.csv
	$(PY) -m rosbag_tools evaluate data/bench --out reports/eval_bench --overwrite --jobs 2

ablate-bench: $(STAMP) data/bench/frames.csv
	$(PY) -m rosbag_tools ablate data/bench --out reports/ablate_bench --overwrite --jobs 2

bench-generate: $(STAMP)
	$(PY) -m benchmarks.generate --out reports/bench_generate.json

station-model: $(STAMP)
	$(PY) -m allo_mrad_ros.render.station_model --out meshes/station.glb

param-study: $(STAMP)
	$(PY) -m benchmarks.param_study --out reports/param_study.json

clean:
	rm -rf build install log *.egg-info .pytest_cache .ruff_cache
