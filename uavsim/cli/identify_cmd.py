"""``uavsim identify SESSION``: class, lumped parameters and PD gains from a relay run.

The session needs an np-mrft (or mrft) run at the beta the network was trained
for. The JSON (``--json``) is that of the session format: ``loop``, ``class``
(of least expected log J under the network's softmax: ``--decision``), ``params`` (the class's lags with K and tau fitted to the
measured point), ``gains`` (kp, kd, derivative_filter_hz for the identified K)
and ``gains_source``: ``table`` (the grid's robust PD of the class at the control
rate over the identified K, the real-time answer) or ``optimum`` (the fitted
model's own optimum, with ``--optimum auto`` when the model is off the grid or
``--optimum always``; its latency in ``gains_optimum``) or ``family`` (lateral loops'
steady cycles: the PD chosen over the models the measured point allows, ``family``
with the member and its latency; ``--no-family`` keeps the table's), plus ``oscillation`` and
``run`` (``uavsim.ident``). ``--write-model`` stores the
identified ``[model]`` in the session (``--force`` replaces an existing one).
A lateral session closes over an attitude loop: ``--attitude-class N`` names
its class (identify the roll or pitch session first); the answer's ``params``
then hold ``T2`` and the outer delay ``tau`` with the attitude loop's
``T_prop``, ``T1`` and ``tau_in``.

    uavsim identify scenarios/sessions/altitude-npmrft --json
    uavsim identify SESSION --models training/runs/small --write-model
    uavsim identify SESSION --plot identify.png
    uavsim identify LATERAL_SESSION --attitude-class 17 --json
"""

from __future__ import annotations

import argparse

from uavsim.cli._common import eprint, print_json, print_table


def register(subparsers) -> None:
    p = subparsers.add_parser("identify", help="identify a loop from a session's NP-MRFT run (DNN-NP-MRFT)",
                              description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("session", help="session folder (or its session.toml)")
    p.add_argument("--models", help="exported model folder, or a root with altitude/ and attitude/ "
                                    "(default: $UAVSIM_MODELS or training/runs)")
    p.add_argument("--run", help="file name of the run to use (default: the first np-mrft run)")
    p.add_argument("--attitude-class", type=int, metavar="N",
                   help="lateral sessions: the attitude class of the roll/pitch loop underneath "
                        "(from `uavsim identify` of its session); picks the network lateral/aNN")
    p.add_argument("--optimum", choices=["never", "auto", "always"], default="never",
                   help="also optimize the identified model's PD at the control rate (~10-20 ms) and answer it "
                        "when the model is off the grid (auto) or always (default never: the table's answer)")
    p.add_argument("--decision", choices=["bayes", "argmax", "fitted", "stable", "blend"], default=None,
                   help="class decision: least expected log J over the network's cost matrix (bayes) or the most likely "
                        "class (argmax), or the candidates judged on the top classes' models fitted to the measured cycle "
                        "(fitted, a few ms), or stability on those models first (stable, with a factor on the PD), or the "
                        "fitted cost plus the grid's (blend, a few ms); default: stable on lateral loops, blend on the "
                        "inner ones (the bundle's decision where it has no cost matrix)")
    p.add_argument("--guard", action=argparse.BooleanOptionalAction, default=None,
                   help="back the table's PD off where the identified model with 5 degrees more lag needs it "
                        "(uavsim.ident.guard, about 1 ms; the answer's guard.scale); default: on for altitude and "
                        "attitude, off for lateral loops")
    p.add_argument("--family", action=argparse.BooleanOptionalAction, default=None,
                   help="lateral: on a steady cycle, answer the PD chosen over the family of models the measured "
                        "point allows (uavsim.ident.family, under a second; the answer's family); default on for "
                        "lateral loops")
    p.add_argument("--second-run", metavar="FILE", default="auto",
                   help="a second relay run of the session at another beta (e.g. -0.3): each class is fitted to "
                        "both measured points and the network's belief weighed by that fit (uavsim.ident.twopoint); "
                        "default auto: the session's run at beta -0.3 where it holds one (lateral: it also keeps "
                        "the family of models to those both points allow, and answers alone where the first run "
                        "is refused); none: the first run alone")
    p.add_argument("--no-second-network", dest="second_network", action="store_false",
                   help="with a second run, weigh by its point alone, not also by the network of its beta beside "
                        "the model folder (uavsim.ident.secondnet: altitude-second, where make train made one)")
    p.add_argument("--write-model", action="store_true", help="write the identified [model] into the session")
    p.add_argument("--force", action="store_true", help="with --write-model: replace an existing [model]")
    p.add_argument("--plot", metavar="PNG", help="write a picture: the measured cycle against the identified "
                                                 "model's, and the measured point on the model's Nyquist plot")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from uavsim.ident.session import identify_session, write_model

    ans = identify_session(args.session, models=args.models, run=args.run, attitude_class=args.attitude_class,
                           optimum=args.optimum, decision=args.decision, guard=args.guard,
                           second_run=None if args.second_run == "none" else args.second_run, family=args.family,
                           second_network=args.second_network)
    if args.write_model:
        folder = write_model(args.session, ans, overwrite=args.force)
        ans["written"] = str(folder)
        eprint(f"wrote [model] to {folder}/session.toml")
    if args.plot:
        from uavsim.learning.figures import identification_png

        ans["plot"] = str(identification_png(args.session, ans, args.plot))
        eprint(f"wrote {args.plot}")
    if args.json:
        print_json(ans)
        return 0
    sr = ans.get("second_run")
    refused = (ans.get("family") or {}).get("refused")
    if refused:
        eprint(f"refused {refused}; answered from the second run {ans['run']} alone: the PD of its point's "
               "family, no class")
    elif sr is not None:
        eprint(f"second run {sr['run']} (beta {sr['beta']:g}) " + (f"not used: {sr['skipped']}" if "skipped" in sr
                                                                  else "weighs the belief"))
        sn = ans.get("second_network")
        if sn is not None:
            eprint(f"and its network {sn['model_dir']} read it" + (
                f" (the first run's point unsteady: the first network's belief to the power {sn['first_weight']:g})"
                if sn["first_weight"] != 1.0 else ""))
    row = {"loop": ans["loop"], "class": ans["class"], **ans["params"], **ans["gains"],
           "gains_source": ans["gains_source"], "period_s": ans["oscillation"]["period"],
           "amplitude": ans["oscillation"]["amplitude"]}
    print_table([row])
    return 0
