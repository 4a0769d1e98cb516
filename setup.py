"""usd-tween: neural motion in-betweening for UsdSkel shots, as a render-farm job."""

from setuptools import find_packages, setup

setup(
    name="usd-tween",
    version="0.1.0",
    description="Fill the frames between an animator's keys with a learned in-betweener, "
    "written back as a non-destructive USD layer.",
    python_requires=">=3.11",
    packages=find_packages(include=["pipeline*", "workers*", "render*", "usd_schemas*", "dailies*"]),
    package_data={
        "usd_schemas": ["*.usda", "*/resources/*.json", "*/resources/*.usda", "*/*.usda"],
        "pipeline.data": ["*.json"],
        "pipeline.adapt": ["*.json"],
        "dailies": ["templates/*.html", "static/*"],
    },
    include_package_data=True,
    install_requires=[
        "numpy>=1.26",
        "scipy>=1.11",
        "usd-core>=25.5",
        "onnxruntime>=1.18",
        "OpenImageIO>=3.0",
        "celery[redis]>=5.4",
        "sqlalchemy>=2.0",
        "typer>=0.12",
        "rich>=13",
        "tqdm>=4.66",
        "moderngl>=5.10",
        "av>=12",
        "opentimelineio>=0.17",
        # the dailies review page (dailies/): server, templates
        "fastapi>=0.115",
        "uvicorn>=0.29",
        "jinja2>=3",
        "gazu>=1.0",  # the Kitsu client: approved takes to the tracker (dailies/kitsu.py)
    ],
    extras_require={
        # torch is pinned: these machines install exactly this CPU build from local disk;
        # any other request pulls a multi-GB CUDA build.
        "train": ["torch==2.13.0", "roma>=1.5", "onnx>=1.16", "onnxscript>=0.2"],
        # Signed farm messages (Celery's auth serializer; docs/farm.md, "Securing the farm").
        "secure": ["celery[auth]>=5.4"],
        "dev": [
            "pytest>=8",
            "pytest-xdist>=3.5",  # make test runs the test files on every core (-n auto)
            "ruff>=0.6",
            "jinja2>=3",
            "threadpoolctl>=3",
            "hypothesis>=6",
            "httpx>=0.27",
            "playwright>=1.40",
            "cryptography>=42",
        ],
    },
    entry_points={
        "console_scripts": ["tween=pipeline.entry:main"],
        # The CLI's commands: each package registers its own, so the core imports neither
        # the farm nor the renderer (pipeline/cli.py reads this group).
        "tween.commands": [
            "bench = pipeline.bench.cli:register",
            "fill = pipeline.fill.cli:register",
            "train = pipeline.train.cli:register",
            "farm = workers.cli:register",
            "render = render.cli:register",
            "rig = pipeline.rig.cli:register",
            "library = pipeline.library.cli:register",
            "dailies = dailies.cli:register",
        ],
        # Model families by kind (pipeline.infer.api's registry): the in-betweener class of a
        # model.json / rig.json kind, called with its folder; folderless ones under every name.
        "tween.models": [
            "generator-onnx = pipeline.infer.generator_onnx:OnnxInbetweener",
            "motion-library = pipeline.library.model:LibraryModel",
        ],
        "tween.rig_models": [
            "rig-ganimator-onnx = pipeline.rig.infer:RigInbetweener",
            "rig = pipeline.rig.infer:RigInbetweener",  # rig.json files written before kinds had names
        ],
        "tween.builtin_models": [
            "interpolation = pipeline.infer.interp:InterpolationInbetweener",
            "spline = pipeline.infer.spline:SplineInbetweener",
        ],
        "tween.model_aliases": ["interp = interpolation"],
    },
)
