"""dls_quadruped: latent-action quadruped locomotion, RL warm starts and a batched sampling MPC."""

from setuptools import find_packages, setup

setup(
    name="dls_quadruped",
    version="0.1.0",
    description="AlienGo in MuJoCo with a latent-action low-level controller, PPO policies and a torch sampling MPC",
    python_requires=">=3.11",
    # experiments/ is a package of the clone, not installed: its scripts run from the repository root as
    # `python -m experiments.<script>` and their default paths (docs/policies, results/) are the clone's
    packages=find_packages(include=["dls_quadruped", "dls_quadruped.*"]),
    package_data={"dls_quadruped": ["robots/aliengo/*.xml", "mpc/*.cpp", "mpc/*.h", "bench/*.npz"]},
    install_requires=[
        "torch>=2.4",
        "mujoco>=4.0",
        "gymnasium>=1.0",
        "rsl-rl-lib>=5.0,<6",
        "pin>=4.1",
        "numpy>=1.26",
        "matplotlib>=3.8",
        "pyyaml>=6.0",
        # progress bars with an ETA on a terminal (dls_quadruped/core/progress.py): well kept, no bar written by hand
        "tqdm>=4.60",
        # gymnasium's ArrayConversion wrapper (numpy view of the torch gymnasium env, docs/gymnasium.md) needs it
        "array-api-compat>=1.11",
    ],
    extras_require={
        # onnxruntime: the tests run the exported ONNX policies and compare them with the TorchScript ones;
        # pytest-xdist: `make test` runs the suite on two workers (one per core of the 2-core CI machine, 1.7x)
        "dev": ["pytest>=8", "pytest-xdist>=3.5", "ruff>=0.5", "onnx>=1.16", "onnxscript>=0.1",
                "onnxruntime>=1.18"],
        # the documentation site (`make docs`, mkdocs.yml): MkDocs renders the Markdown pages as they are,
        # mkdocstrings builds the API pages from the docstrings by reading the source (no import), Material is
        # the theme; `make test` installs it so the suite's strict build (tests/test_docs_site.py) runs in CI
        "docs": ["mkdocs>=1.6", "mkdocs-material>=9.5", "mkdocstrings[python]>=0.26"],
        # the MuJoCo Warp simulator backends (scene.backend: cuda / warp-cpu, sim/warp_backend.py, docs/gpu.md);
        # optional: it pulls warp-lang (~100 MB) and compiles kernels on first use, the CPU backend needs none of it.
        # Pinned: the backend uses MuJoCo Warp's two-phase step, its CSR mass matrix and batched model fields,
        # whose names and layouts change between releases.
        "gpu": ["mujoco-warp==4.0.0", "warp-lang==1.19.0"],
    },
)
