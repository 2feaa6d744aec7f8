"""Identification: a relay run in, a class, a model and PD gains out (DNN-NP-MRFT), without torch.

Downstream of ``uavsim.data`` (the shared preprocessing) and ``uavsim.learning``
(the exported network); reads nothing but the model bundle.

- ``bundle``: the exported model folder and everything identification needs beside the
  network (class table with the grid's PD table, rule, preprocessing settings, lateral
  attitude loop); where model folders are found.
- ``cycle``: the cycle identification uses, and the checks that refuse what is not one.
- ``response``: the measured fundamental response and the models fitted to it.
- ``select``: the class: least expected log J under the network's softmax over the bundle's
  cost matrix (or the most likely class, ``decision="argmax"``).
- ``gains``: the table's PD for the identified gain; the fitted model's optimum.
- ``family``: lateral loops' steady cycles: the PD chosen over the family of models the
  measured point allows.
- ``guard``: the inner loops' back-off where a little more lag would ruin the answer.
- ``twopoint``, ``lagfamily``: a second relay run's point: the belief weighed by both points; the
  inner loops' lag pairs both points allow, which the guard backs off no further than.
- ``session``: the session-level API (``identify_session``, ``write_model``).
- ``evaluate``: off-grid evaluation against each process's optimum (``uavsim evaluate``).

    from uavsim.ident import identify_session
    ans = identify_session("scenarios/sessions/altitude-npmrft", models="training/runs/small")
    ans["class"], ans["params"], ans["gains"], ans["gains_source"]
"""

from uavsim.ident.bundle import ModelBundle, load_bundle, resolve_model_dir
from uavsim.ident.session import identify_arrays, identify_cycle, identify_session, write_model

__all__ = ["ModelBundle", "load_bundle", "resolve_model_dir", "identify_arrays", "identify_cycle", "identify_session",
           "write_model"]
