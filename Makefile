# dls_quadruped: `make demo` (main job, small default: student-warm-started MPC vs naive MPC vs RL), `make test`, `make bench`, `make train TASK=...`.
# A fresh clone needs nothing but python3: the first target creates .venv and installs what it needs.

PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
# torch is installed first and pinned, from PyTorch's CPU index by default: PyPI's Linux torch is the CUDA build,
# several GB of CUDA libraries a CPU machine never uses (pip still takes a local wheel of the same version first,
# e.g. from a find-links folder; one retry, so an index out of reach costs seconds). On a GPU machine name a CUDA
# index (docs/install.md), e.g.
# `make TORCH_INDEX="--index-url https://download.pytorch.org/whl/cu128" install-gpu`; TORCH_INDEX= uses pip's own.
TORCH_SPEC ?= torch==2.13.0
TORCH_INDEX ?= --index-url https://download.pytorch.org/whl/cpu
STAMP := $(VENV)/.installed

NUM_ENVS ?= 64
SECONDS_PER_PHASE ?= 5
OUT ?= results

.PHONY: install install-gpu install-offline wheelhouse gpu-pack gpu-caches gpu-aot gpu-plan gpu-check test test-gpu-path test-all docs demo demo-balance bench bench-env bench-terrain bench-mpc bench-rl bench-ppo bench-closed-loop bench-gym bench-device lint clean

# One stamp per (TORCH_SPEC, TORCH_INDEX): changing either re-installs torch (--force-reinstall: pip would keep a
# 2.13.0+cpu build for a cu128 index's torch==2.13.0, the same version to it).
TORCH_STAMP := $(VENV)/.torch-$(shell printf '%s|%s' '$(TORCH_SPEC)' '$(TORCH_INDEX)' | cksum | cut -d' ' -f1)

$(TORCH_STAMP):
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	rm -f $(VENV)/.torch-*
	$(PY) -m pip install -q --retries 1 --force-reinstall $(TORCH_INDEX) "$(TORCH_SPEC)"
	touch $@

$(STAMP): setup.py $(TORCH_STAMP)
	$(PY) -m pip install -q -e ".[dev,docs]"
	touch $(STAMP)

install: $(STAMP)

# the optional MuJoCo Warp backends (scene.backend: cuda / warp-cpu; docs/gpu.md). On a GPU machine name a CUDA
# torch wheel (TORCH_INDEX above); the check below says so when the torch left in .venv is a CPU build
# (fine for warp-cpu, not for cuda).
install-gpu: $(STAMP)
	$(PY) -m pip install -q -e ".[dev,gpu]"
	@$(PY) -c "import torch, sys; sys.exit(0 if torch.version.cuda else 1)" || \
		echo "install-gpu: the torch in $(VENV) ($$($(PY) -c 'import torch; print(torch.__version__)')) is a CPU build: \
	backend warp-cpu works, cuda does not. For a GPU: make TORCH_SPEC=torch==2.13.0 \
	TORCH_INDEX='--index-url https://download.pytorch.org/whl/cu128' install-gpu (docs/gpu.md)"

# Air-gapped GPU nodes (docs/gpu.md "Offline install"): on a machine with network, `make wheelhouse` downloads every
# wheel the [gpu] install needs for WHEEL_PYTHON on glibc x86-64 Linux into WHEELHOUSE (versions: the ones
# installed here); WHEEL_EXCLUDE drops what the node already has (e.g. torch). On the node,
# `make install-offline WHEELHOUSE=...` installs from the folder with no network.
WHEELHOUSE ?= wheelhouse
WHEEL_PYTHON ?= 3.12
WHEEL_EXCLUDE ?=
wheelhouse: install-gpu
	$(strip $(PY) -m dls_quadruped.tools.wheelhouse --out $(WHEELHOUSE) --python-version $(WHEEL_PYTHON) \
		$(if $(WHEEL_EXCLUDE),--exclude $(WHEEL_EXCLUDE),))

# A GPU node that takes files in size-limited transfers and has torch but no network (docs/gpu.md "Offline install"):
# the [gpu] wheels unpacked into one import folder without Warp's CPU compiler, packed with xz into parts of at most
# GPU_PACK_PART_MB, and the one line that unpacks them there (GPU_PACK/unpack.sh)
GPU_PACK ?= .gpu_pack
GPU_PACK_PART_MB ?= 48
gpu-pack: install-gpu
	$(PY) -m dls_quadruped.tools.gpu_pack --out $(GPU_PACK) --part-mb $(GPU_PACK_PART_MB) --where $(GPU_PACK)

# the compile caches of a GPU node's jobs (run them with WARP_CACHE_PATH=$(GPU_CACHES)/warp and
# TORCHINDUCTOR_CACHE_DIR=$(GPU_CACHES)/inductor), packed the same way for the next node (docs/gpu.md "Cold start")
GPU_CACHES ?= /tmp/gpu_caches
gpu-caches:
	$(strip $(if $(wildcard $(STAMP)),$(PY),$(PYTHON)) -m dls_quadruped.tools.gpu_pack --caches $(GPU_CACHES) \
		--out $(GPU_PACK) --part-mb $(GPU_PACK_PART_MB) --where $(GPU_PACK))

# Warp's CUDA kernels of MuJoCo Warp (base, rough) and the MPC compiled here, without a GPU (Warp's NVRTC), into
# GPU_CACHES/warp for a node of architecture GPU_ARCH (90: H100, H200); then `make gpu-caches` packs them
GPU_ARCH ?= 90
gpu-aot: install-gpu
	$(PY) -m dls_quadruped.tools.warp_aot --cache $(GPU_CACHES)/warp --arch $(GPU_ARCH)

# the calls of one lease: the tree (docs/ left behind but for what the lease reads) and the parts in GPU_PACK, each
# call's size against the 64 MiB a call carries, and the git lines that leave docs/ behind and restore it
gpu-plan:
	$(strip $(if $(wildcard $(STAMP)),$(PY),$(PYTHON)) -m dls_quadruped.tools.gpu_pack --plan --out $(GPU_PACK))

install-offline:
	test -d "$(WHEELHOUSE)" || { echo "install-offline: WHEELHOUSE=$(WHEELHOUSE) is not a folder (make wheelhouse)"; exit 2; }
	test -x $(PY) || $(PYTHON) -m venv --system-site-packages $(VENV)
	$(PY) -m pip install -q --no-index --find-links "$(WHEELHOUSE)" "dls_quadruped[gpu]"
	touch $(TORCH_STAMP) && touch $(STAMP)  # the node's torch counts as installed: no online step later

# The ten-minute GPU check (docs/gpu.md "GPU check"): versions, compile time, cuda-vs-cpu trajectories, host syncs,
# env steps/s, the MPC, then PPO on base with the time left; a JSON report written as it goes. Without CUDA it runs
# on warp-cpu at small sizes. GPU_CHECK_ARGS="--budget-s 600 --train-envs 4096" etc.
GPU_CHECK_ARGS ?=
gpu-check:
	$(if $(wildcard $(STAMP)),$(PY),$(PYTHON)) -m dls_quadruped.bench.gpu_check --out $(OUT)/gpu_check $(GPU_CHECK_ARGS)

# TEST_WORKERS pytest-xdist workers (one per core; 0: one process); a test file stays on one worker, so the
# module-scoped fixtures are built once
TEST_WORKERS ?= 2
test: $(STAMP)
	$(PY) -m pytest -n $(TEST_WORKERS) --dist loadfile

# the code paths only a GPU runs, exercised on warp-cpu (MuJoCo Warp on Warp's CPU device, scene.compile on):
# the [gpu] extra and every test of the Warp backends, the compiled env step and the GPU check, slow ones included
# (~20-40 min on 2 cores, most of it compiling; not part of .ci/run)
# Under another torch (docs/gpu.md): make VENV=.venv-torch211 TORCH_SPEC=torch==2.11.0 TORCH_INDEX= test-gpu-path
GPU_PATH_TESTS ?= tests/sim/test_warp_backend.py tests/sim/test_warp_graph.py tests/sim/test_warp_collision.py \
	tests/sim/test_warp_control.py tests/envs/test_host_sync.py tests/envs/test_compile_guards.py \
	tests/bench/test_gpu_check.py tests/core/test_compile.py tests/mpc/test_warp_solve.py tests/closed_loop/test_device_loop.py \
	tests/bench/test_device_loop_bench.py tests/envs/test_env_graph.py tests/tools/test_warp_aot.py \
	tests/tools/test_gpu_lease.py
test-gpu-path: install-gpu
	$(strip $(PY) -m pytest -n $(TEST_WORKERS) --dist loadfile -m "slow or not slow" $(GPU_PATH_TESTS))

test-all: $(STAMP)
	$(PY) -m pytest -n $(TEST_WORKERS) --dist loadfile -m "slow or not slow"

lint: $(STAMP)
	$(PY) -m ruff check dls_quadruped tests

# the documentation site (mkdocs.yml, docs/index.md): site/index.html, the API pages from the docstrings; --strict
# makes every warning an error, a broken link or anchor included (tests/test_docs_site.py runs the same build)
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict

# The main job (thesis 7.3): the committed student warm-starting the sampling MPC beside the naive MPC and
# the RL expert alone, DEMO_EPISODES robots each on the simple task, M = 10 000 (docs/demo.md).
DEMO_EPISODES ?= 4
DEMO_SECONDS ?= 6
DEMO_ARGS ?=

demo: $(STAMP)
	OMP_NUM_THREADS=1 $(PY) -m dls_quadruped.closed_loop --controllers rl_warm_start,naive_warm_start,rl_baseline \
		--episodes $(DEMO_EPISODES) --seconds $(DEMO_SECONDS) --video --out $(OUT)/demo $(DEMO_ARGS)

# The foundation's demo: N robots stand, then trot in place under the balance controller.
demo-balance: $(STAMP)
	$(PY) -m dls_quadruped.demo --num-envs $(NUM_ENVS) --seconds $(SECONDS_PER_PHASE) --out $(OUT)/demo_balance

# Every benchmark writes JSON under $(OUT)/bench only (UPDATE_DOCS=1: bench-mpc also rewrites docs/benchmarks.md).
# `make bench DEVICE=cuda` runs the device benchmark instead (env steps/s per N, MPC solve, closed loop on
# the GPU; docs/gpu.md); `make bench-device DEVICE=cpu BACKEND=warp-cpu` runs it anywhere
bench: $(if $(filter cuda%,$(DEVICE)),bench-device,bench-env bench-terrain bench-mpc bench-rl bench-ppo bench-closed-loop)

bench-device: $(STAMP)
	$(strip $(PY) -m dls_quadruped.bench.device --device $(or $(DEVICE),cuda) $(if $(BACKEND),--backend $(BACKEND),) \
		--out $(OUT)/bench)

bench-env: $(STAMP)
	$(PY) -m dls_quadruped.bench.env --out $(OUT)/bench

bench-terrain: $(STAMP)
	$(PY) -m dls_quadruped.bench.terrain --out $(OUT)/bench

# UPDATE_DOCS=1: the MPC benchmarks also rewrite their sections of docs/benchmarks.md (default: only $(OUT)/bench)
UPDATE_DOCS ?=
bench-mpc: $(STAMP)
	$(PY) -m dls_quadruped.bench.mpc --out $(OUT)/bench $(if $(UPDATE_DOCS),--update-docs,)

bench-rl: $(STAMP)
	$(PY) -m dls_quadruped.bench.rl_env --out $(OUT)/bench

# one PPO iteration split into collection and update, samples/s of each, rsl-rl's stock update beside
# learning/fast_update.py's, interleaved (N = 256 and 1024; docs/reports/benchmarks.md "PPO update");
# BENCH_PPO_ARGS="--variants fast fast_bf16" adds the bf16 update (pays only on CPUs with bf16 instructions)
BENCH_PPO_ARGS ?=
bench-ppo: $(STAMP)
	OMP_WAIT_POLICY=PASSIVE $(PY) -m dls_quadruped.bench.ppo_update --out $(OUT)/bench $(BENCH_PPO_ARGS)

# the gymnasium view's cost beside the native env (rough, N = 1024; docs/gymnasium.md "Cost"), not part of `make bench`
bench-gym: $(STAMP)
	OMP_NUM_THREADS=1 $(PY) -m dls_quadruped.bench.gym_env --out $(OUT)/bench

bench-closed-loop: $(STAMP)
	OMP_NUM_THREADS=1 $(PY) -m dls_quadruped.bench.closed_loop --robots 16 64 --paths fused torch --out $(OUT)/bench

clean:
	rm -rf $(VENV) results site .pytest_cache

# ---------------------------------------------------------------------------------------------
# RL training and playback.
# `make train TASK=rough NUM_ENVS=256 ITERATIONS=500 DEVICE=cpu SEED=0 RESUME=1`, see docs/train.md.
# Defaults sized for the 2-core dev machine (base, 256 envs: 6.2 s per iteration on the loaded 2-core VM, so
# ~51 min for 500; docs/workflow.md). NUM_ENVS on the command line overrides TRAIN_NUM_ENVS.
TASK ?= base
TRAIN_NUM_ENVS ?= $(if $(filter command line environment,$(origin NUM_ENVS)),$(NUM_ENVS),256)
ITERATIONS ?= 500
# torch intra-op threads of the trainer during collection (the simulator workers own the cores then).
# The PPO update runs on UPDATE_THREADS (empty: every core; the workers idle then), with OpenMP's idle
# threads sleeping (OMP_WAIT_POLICY=PASSIVE): spinning, 2 threads were 3-8x slower than 1 on cores shared
# with other processes; sleeping, within +-10 % of 1 at load 4-5 (docs/train.md "Update speed").
# UPDATE_THREADS=0: the update on TRAIN_THREADS too.
TRAIN_THREADS ?= 1
UPDATE_THREADS ?=
DEVICE ?= cpu
# empty: 0 for a new run, the checkpoint's for RESUME=1 / RESUME_FROM (another one is refused)
SEED ?=
RESUME ?=
# RESUME_FROM=runs/base/<run>/model_<it>.pt continues from a checkpoint file (e.g. copied from another
# machine) in a new run dir; CHECKPOINT_COPY=PATH also writes every checkpoint
# to PATH (the file to commit). See docs/train.md, "Runs that span machines".
RESUME_FROM ?=
CHECKPOINT_COPY ?=
# INIT_FROM=docs/policies/base_networks.pt starts the run from the base expert's actor and critic
# (fine-tuning; how the speed, rough and climb experts were trained, docs/train.md).
INIT_FROM ?=
INIT_STD ?=
# simulator worker processes (empty: the task's scene.num_workers, one per core; 0 = in-process)
TRAIN_WORKERS ?=
# simulator backend (empty: the task's scene.backend, cpu); BACKEND=cuda DEVICE=cuda runs MuJoCo Warp on the GPU
# (make install-gpu; docs/gpu.md)
BACKEND ?=
# CHECKPOINT: what `make play` plays (a model_<it>.pt, an exported policy.pt2 or docs/policies/<name>_actor.pt);
# empty: the newest checkpoint of the task's latest run under runs/<task>/ (docs/play.md)
CHECKPOINT ?=
PLAY_SECONDS ?= 10
# SET="agent.algorithm.entropy_coef=0.0 env.episode_length_s=10": task-file overrides for train, play and eval,
# space-separated KEY=VALUE pairs, each passed as --set (write YAML lists without spaces: [0.5,1.0]; docs/env.md)
SET ?=
SET_ARGS = $(foreach kv,$(SET),--set '$(kv)')

.PHONY: train play tasks

train: $(STAMP)
	$(strip OMP_NUM_THREADS=$(TRAIN_THREADS) OMP_WAIT_POLICY=PASSIVE $(PY) -m dls_quadruped.learning.train --task $(TASK) \
		--num-envs $(TRAIN_NUM_ENVS) --iterations $(ITERATIONS) \
		--device $(DEVICE) $(if $(SEED),--seed $(SEED),) $(if $(RESUME),--resume,) $(if $(TIME_LIMIT),--time-limit $(TIME_LIMIT),) \
		$(if $(INIT_FROM),--init-from $(INIT_FROM),) \
		$(if $(INIT_STD),--init-std $(INIT_STD),) \
		$(if $(RESUME_FROM),--resume-from $(RESUME_FROM),) $(if $(CHECKPOINT_COPY),--checkpoint-copy $(CHECKPOINT_COPY),) \
		$(if $(TRAIN_WORKERS),--num-workers $(TRAIN_WORKERS),) $(if $(UPDATE_THREADS),--update-threads $(UPDATE_THREADS),) \
		$(if $(BACKEND),--backend $(BACKEND),) $(SET_ARGS))

play: $(STAMP)
	$(strip $(PY) -m dls_quadruped.learning.play --task $(TASK) --seconds $(PLAY_SECONDS) \
		$(if $(CHECKPOINT),--checkpoint $(CHECKPOINT),) $(SET_ARGS))

# the registered tasks (tasks/*.yaml), one line each
tasks: $(STAMP)
	$(PY) -m dls_quadruped.list_tasks

# ---------------------------------------------------------------------------------------------
# Policy evaluation (scenarios in dls_quadruped/eval/scenarios.py, see docs/eval.md).
# `make eval POLICY=docs/policies/base_actor.pt SCENARIO=simple EPISODES=256 EVAL_OUT=results/eval/base`
# Scenarios: simple, forward, survival, survival_sweep, stairs, speed, omni, cot, gait. EPISODES is per condition
# (per speed, step height, grid cell); empty = the scenario's small default.
POLICY ?= docs/policies/base_actor.pt
SCENARIO ?= simple
EPISODES ?=
EVAL_OUT ?=

.PHONY: eval

eval: $(STAMP)
	$(strip OMP_NUM_THREADS=1 $(PY) -m dls_quadruped.eval --policy $(POLICY) --scenario $(SCENARIO) \
		$(if $(EPISODES),--episodes $(EPISODES),) $(if $(EVAL_OUT),--out $(EVAL_OUT),) $(SET_ARGS))

# Choose a run's checkpoint on the scenario's validation episodes (docs/train.md "Choosing a checkpoint"):
# `make select RUN=runs/base/<run> SCENARIO=simple EVERY=50` writes RUN/selection/<scenario>/selection.json
RUN ?=
EVERY ?=

.PHONY: select

select: $(STAMP)
	$(strip OMP_NUM_THREADS=1 $(PY) -m dls_quadruped.eval.select $(RUN) --scenario $(SCENARIO) \
		$(if $(EVERY),--every $(EVERY),) $(if $(EPISODES),--episodes $(EPISODES),))

# ---------------------------------------------------------------------------------------------
# Distillation of an expert into a horizon student (docs/distill.md). Defaults: Table 7
# (tasks/agents/distill.yaml), first-spline, H = 10, dt = 0.02 s, DAgger alpha = 0.6.
# `make distill EXPERT=... ENCODING=discrete-discrete HORIZON=5 DT=0.04 ALGO=naive EPOCHS=20`
# DISTILL_TASK: the env task the expert acts in (default: the config's, base), e.g. speed_full_range.
EXPERT ?= docs/policies/base_actor.pt
ENCODING ?= first-spline
HORIZON ?= 10
DT ?= 0.02
ALGO ?= dagger
EPOCHS ?= 30
DISTILL_NUM_ENVS ?= 128
DISTILL_OUT ?= results/distill
DISTILL_ARGS ?=
DISTILL_TASK ?=

.PHONY: distill

# RESUME=1 continues with the run's stored settings (its distill.yaml): of EXPERT ... DISTILL_NUM_ENVS only the ones
# given on the command line (or in the environment) are passed, as overrides (another expert or encoding is refused)
given = $(filter command line environment environment override override,$(origin $(1)))
distill_flag = $(if $(or $(if $(RESUME),,new),$(call given,$(2))),$(1) $($(2)),)

distill: $(STAMP)
	$(strip OMP_NUM_THREADS=$(TRAIN_THREADS) $(PY) -m dls_quadruped.learning.distill $(call distill_flag,--expert,EXPERT) \
		$(call distill_flag,--encoding,ENCODING) $(call distill_flag,--horizon,HORIZON) $(call distill_flag,--dt,DT) \
		$(call distill_flag,--algo,ALGO) $(call distill_flag,--epochs,EPOCHS) \
		$(call distill_flag,--num-envs,DISTILL_NUM_ENVS) --out $(DISTILL_OUT) $(if $(DISTILL_TASK),--task $(DISTILL_TASK),) \
		$(if $(RESUME),--resume,) $(DISTILL_ARGS))
