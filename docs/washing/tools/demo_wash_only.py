"""`cellctl demo` cut to its first cycle (the new bin's whole-bin plan) and its wash-and-verify cycle,
with the powder seed from ``WASH_SEED`` (18 is the demo's own): the wash story on its own, ~8 min on a
quiet 2-core machine. Arguments as `cellctl demo`'s. docs/washing/README.md (round 5)."""

import os, sys
import cellctl.cli.demo as D
orig = D._stories
def only_wash(bt, home, nudged, moved, whole, wash):
    s = orig(bt, home, nudged, moved, whole, True)
    w = [x for x in s if x.params.get("mode") == "wash_and_verify"]
    w[0].scenario = {**w[0].scenario, "seed": int(os.environ["WASH_SEED"])}
    return [s[0], *w]
D._stories = only_wash
from cellctl.cli import main
sys.exit(main(sys.argv[1:]))
