"""uwval's embedded defaults (installed as ``uwval.data``): vehicle presets, experiments,
thresholds and golden baselines. Read them through :func:`uwval.resources.data_path`."""
