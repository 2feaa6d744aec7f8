"""DNN-NP-MRFT learning: network, J-weighted loss, trainer, evaluation, export, identification.

The classifier maps one preprocessed limit cycle (``uavsim.data.preprocess``)
to a class of the loop's grid (``uavsim.tuning.grid``); the class gives the
lumped time parameters and the rule gains for K = 1, the cycle amplitude gives K.

    from uavsim.learning.train import train_from_recipe
    report = train_from_recipe("training/small.toml")          # writes training/runs/small/
    from uavsim.learning.identify import identify_session
    identify_session("scenarios/sessions/altitude-npmrft")      # JSON of docs/formats/session.md

Modules: ``model`` (network), ``loss`` (J-weighted softmax cross-entropy),
``train`` (recipes, checkpoints, resume, early stopping), ``evaluate``
(held-out and off-grid metrics, closed-loop ISE criterion), ``export``
(weights.npz, ONNX and TorchScript artefacts; ``Predictor`` runs weights.npz with
numpy alone), ``identify`` (sessions -> class, parameters, gains; no torch),
``figures`` (identification and training PNGs). Only ``model``, ``loss`` and
``train`` need torch (``pip install 'uavsim[train]'``).
"""
