"""DNN-NP-MRFT learning: network, J-weighted loss, trainer, export.

The classifier maps one preprocessed limit cycle (``uavsim.data.preprocess``)
to a class of the loop's grid (``uavsim.tuning.grid``); the exported folder
carries the network and what identification (``uavsim.ident``) needs beside it.

    from uavsim.learning.train import train_from_recipe
    report = train_from_recipe("training/small.toml")          # writes training/runs/small/

Modules: ``model`` (network), ``loss`` (J-weighted softmax cross-entropy),
``train`` (recipes, checkpoints, resume, early stopping), ``export``
(weights.npz, ONNX and TorchScript artefacts; ``Predictor`` runs weights.npz with
numpy alone), ``bundle`` (the identification section of an export's meta.json),
``figures`` (identification and training PNGs), ``decision`` (the class decision: least
expected J under the softmax). Only ``model``, ``loss`` and
``train`` need torch (``pip install 'uavsim[train]'``).
"""
