"""Robot 2 as a lying insider over the network (tests/test_insider.py): ``swarmloc node`` with its own valid key, every
message its node sends shifted 100 m on the way out (tests/_insider.py).

    python tests/net_insider.py node --robot 2 ...   (the arguments of ``python -m swarmloc.cli node``)
"""

from __future__ import annotations

import sys

from _insider import SHIFT, lying

import swarmloc.net.entry as entry
from swarmloc.cli import main

made = entry.make_node


def make_lying_node(*args, **kwargs):
    node = made(*args, **kwargs)
    node.__class__ = lying(type(node))
    print(f"net_insider: robot {node.robot} is lying: every message shifted {SHIFT} m", flush=True)
    return node


entry.make_node = make_lying_node

if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
