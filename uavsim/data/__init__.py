"""Training data: recipes, the shared preprocessing, generation and dataset files.

- ``uavsim.data.recipe``: strict TOML recipes (``datasets/*.toml``).
- ``uavsim.data.preprocess``: THE relay-cycle preprocessing, shared by training-set
  generation and identification of flight sessions.
- ``uavsim.data.generate``: NP-MRFT episodes in MuJoCo -> inputs, resumable, local
  threads or Dask; its steps are ``plan`` (every draw, before anything runs),
  ``episodes`` (a chunk on the MuJoCo loop), ``backends`` (threads, Dask, resume
  state) and ``assemble`` (the file).
- ``uavsim.data.noise_trace``: study noise precomputed for whole episodes.
- ``uavsim.data.h5``: the ``uavsim-dataset/1`` HDF5 writer and validating reader.

    from uavsim.data.recipe import load_recipe
    from uavsim.data.generate import generate
    from uavsim.data.h5 import open_dataset
    generate(load_recipe("datasets/small.toml"), "datasets/small.h5")
    ds = open_dataset("datasets/small.h5"); ds.inputs.shape, ds.labels, ds.J
"""
