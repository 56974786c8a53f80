"""`factr2 twin`: serve a rig's SIMULATED hardware (MuJoCo twin) on the real wire protocols until Ctrl-C.

Another process (or `factr2 teleop --rig <the printed rig>` style tools) then talks to the printed pty
paths and python-can virtual channels exactly as to real devices. Virtual CAN channels live inside one
process, so CAN clients must run in this process (serve_twin) -- the pty paths work from anywhere.
"""

from __future__ import annotations

import time

HELP = "serve a sim rig's twin (Dynamixel on a pty, CAN on python-can virtual channels) until Ctrl-C"


def add_arguments(parser) -> None:
    parser.add_argument("--rig", default="sim-piper", help="built-in sim rig name or path to a rig .toml "
                        "(default: sim-piper)")
    parser.add_argument("--twin-effect", default=None, metavar="MODULE:FUNCTION",
                        help="undeclared actuator effect f(t, q, q_dot) -> tau [N*m] added inside the "
                        "followers' drives (shows in measured current only)")
    parser.add_argument("--seed", type=int, default=None, help="noise seed (default: the rig's)")
    parser.add_argument("--seconds", type=float, default=None,
                        help="stop after this many seconds instead of waiting for Ctrl-C")
    parser.add_argument("--list", action="store_true", help="list the built-in rigs and exit")
    parser.add_argument("--watch", default=None, metavar="DIR",
                        help="serve CAN on pty links too (other processes can open them), write "
                        "DIR/app_rig.toml (the rig as a real rig reaching this twin) and at Ctrl-C / SIGTERM "
                        "what the motors did (DIR/watch.npz, DIR/events.json: hardware/process_twin.py)")
    parser.add_argument("--hand", action="store_true", help="with --watch: a scripted hand moves the leaders")


def run(args) -> int:
    from hardware.connect import serve_twin
    from hardware.registry import device_kind
    from hardware.rigs import list_rigs, load_rig

    if args.list:
        for name in list_rigs():
            r = load_rig(name)
            print(f"{name:22s} {'sim ' if r.simulated else 'real'}  {r.description}")
        return 0
    if args.watch:
        from pathlib import Path

        from hardware.process_twin import serve

        print(f"twin of rig {args.rig} in real time (SIMULATED hardware); its app rig: "
              f"{args.watch}/app_rig.toml", flush=True)
        return serve(args.rig, Path(args.watch), args.seed, args.hand)
    server = serve_twin(args.rig, effect=args.twin_effect, seed=args.seed)
    try:
        rig = server.rig
        print(f"twin of rig {rig.name} running in real time (SIMULATED hardware)", flush=True)
        for d in rig.leaders + rig.followers:
            dev, kind = server.twin.devices[d.name], device_kind(d.driver)
            if dev.wire == "serial":
                print(f"  {d.name}: {kind.protocol} on {dev.endpoint}", flush=True)
            elif dev.wire == "can":
                print(f"  {d.name}: {kind.protocol} (python-can interface 'virtual', this process only) on "
                      f"channel {dev.endpoint}", flush=True)
            else:
                print(f"  {d.name}: no wire protocol (driver {d.driver!r}: open the rig in-process with "
                      "hardware.connect.open_rig)", flush=True)
        for d in rig.leaders + rig.followers:
            err = server.twin.devices[d.name].body_error
            if err is not None:  # docs/twin_model.md "The true body"
                r = err.mass_true / err.mass_desc
                print(f"  {d.name}: true body, link masses x{r.min():.2f}-{r.max():.2f} of the description "
                      f"'{err.arm}' (seed {err.seed}; [twin] description_error = false: exact)", flush=True)
        if server.twin.hook_spec:
            print(f"  undeclared effect on the followers: {server.twin.hook_spec}", flush=True)
        print("Ctrl-C to stop", flush=True)
        t_end = None if args.seconds is None else time.monotonic() + args.seconds
        while t_end is None or time.monotonic() < t_end:
            time.sleep(0.1 if t_end is None else max(0.0, min(0.1, t_end - time.monotonic())))
        print(f"stopped after {server.sim_time:.2f} s simulated ({server.twin.overruns} overruns)",
              flush=True)
    finally:
        server.stop()
    return 0
