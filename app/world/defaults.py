"""The world a clip is draped on when nothing is configured (no [[world]] table, no --world,
--imagery or --terrain, no GEOFUSE_WORLD): open sources that need no key and whose terms allow
such use, where the network answers (a short probe first: PROBE_TIMEOUT_S); the flat ground
where it does not, said with how to configure a source.

- imagery: EOX's Sentinel-2 cloudless 2016 mosaic (app.world.providers.OWN), the one global,
  keyless imagery whose licence (CC BY 4.0, the credit shown and written) allows any use;
  Esri World Imagery ties its use to Esri's products and forbids storing its tiles, later
  Sentinel-2 cloudless years are non-commercial (CC BY-NC-SA 4.0), NASA GIBS is public domain
  but 250 m a pixel at best. 10 m a pixel: the ground around a drone's track, not its detail.
- terrain: the Terrain Tiles on the Registry of Open Data on AWS (Mapzen's Terrarium PNG tiles:
  SRTM, GMTED2010, 3DEP, EU-DEM... to zoom 15), open data needing no key, credited as the
  Tilezen attribution asks.

GEOFUSE_DEFAULT_IMAGERY and GEOFUSE_DEFAULT_TERRAIN replace either (any spelling --imagery
and --terrain take, a provider's name included; 'none': without it), which is how the tests
point the defaults at a server of their own on the loopback. No test reaches the internet: the
suite sets GEOFUSE_WORLD=none (tests/conftest.py).
"""

from __future__ import annotations

import os
import threading
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Iterable

NAME = "open"  # the default world, as messages name it
IMAGERY = "EOX.Sentinel2Cloudless2016"
TERRAIN = "AWS.Terrarium"
ENV_IMAGERY = "GEOFUSE_DEFAULT_IMAGERY"
ENV_TERRAIN = "GEOFUSE_DEFAULT_TERRAIN"
NONE = "none"
PROBE_TIMEOUT_S = 2.0  # the most a command waits to learn whether the default sources answer


def spellings() -> tuple[str | None, str | None]:
    """(imagery, terrain) of the default world, as --imagery and --terrain spell them (the
    environment's replacements where set), None for one left out ('none')."""
    out = []
    for env, default in ((ENV_IMAGERY, IMAGERY), (ENV_TERRAIN, TERRAIN)):
        value = os.environ.get(env, "").strip() or default
        out.append(None if value.lower() == NONE else value)
    return out[0], out[1]


def _answers(url: str, timeout_s: float, result: list[bool]) -> None:
    request = urllib.request.Request(url, method="HEAD")
    try:
        with urllib.request.urlopen(request, timeout=timeout_s):
            pass
        result.append(True)
    except urllib.error.HTTPError:  # a refusal is an answer: the network is there
        result.append(True)
    except (OSError, ValueError):
        result.append(False)


def network_answers(urls: Iterable[str], timeout_s: float = PROBE_TIMEOUT_S) -> bool:
    """Whether any of the http(s) servers of `urls` answers a HEAD request within timeout_s
    seconds in all (name resolution included: each is asked on a thread of its own, left behind
    when it takes longer). Local files answer at once."""
    hosts = []
    for url in urls:
        parts = urllib.parse.urlsplit(url)
        if parts.scheme not in ("http", "https"):
            return True
        hosts.append(f"{parts.scheme}://{parts.netloc}/")
    roots = list(dict.fromkeys(hosts))
    if not roots:
        return True
    result: list[bool] = []
    done = threading.Event()

    def ask(root: str) -> None:
        _answers(root, timeout_s, result)
        if any(result) or len(result) == len(roots):
            done.set()

    for root in roots:
        threading.Thread(target=ask, args=(root,), name="geofuse-probe", daemon=True).start()
    done.wait(timeout_s)
    return any(result)
