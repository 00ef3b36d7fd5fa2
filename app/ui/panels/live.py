"""The Live panel (a stream open instead of a session): what is shown (the live edge or a moment
under review) and, beside it, "GNSS REJECTED" or "NO GNSS" while the fixes lie or are missing
(the Stats panel says the lie), a scrubber over everything recorded so far (a band along it:
each frame's GNSS status, green used, red rejected, grey missing), "Live" back to the edge, and
what arrived and what was lost."""

from __future__ import annotations

from imgui_bundle import imgui

from app.camera.fixes import MISSING, REJECTED
from app.ui import gnss
from app.ui.panels.timeline import band
from app.ui.panels.widgets import AMBER, colour, run, window


def draw(v, now: float) -> None:
    """This frame's panel (v: the Viewer)."""
    if window("Live"):
        L = v.live
        r = L.feed.update_counts()
        span = L.recorded_span()
        shown = "-" if L.shown_s is None else f"{L.shown_s:7.2f} s"
        if L.review_s is None:
            imgui.text_colored(colour((0.3, 1.0, 0.4, 1.0)), "LIVE")
        else:
            imgui.text_colored(colour(AMBER), "REVIEW")
            imgui.same_line()
            if imgui.button("Live"):
                run(v, "live", "edge", now)
        if L.feed.gnss_now in (REJECTED, MISSING):  # the Stats panel says why
            imgui.same_line()
            imgui.text_colored(
                colour(gnss.COLOURS[L.feed.gnss_now]),
                "GNSS REJECTED" if L.feed.gnss_now == REJECTED else "NO GNSS",
            )
        imgui.same_line()
        changed, on = imgui.checkbox("follow", v.nav.mode == "follow")
        if changed:
            run(v, "view", "follow" if on else "free", now)
        imgui.same_line()
        behind = (
            ""
            if span is None or L.shown_s is None
            else f"  ({span[1] - L.shown_s:.1f} s behind the newest)"
        )
        imgui.text(f"showing {shown}{behind}")
        if span is not None and span[1] > span[0]:
            imgui.set_next_item_width(-1)
            t = L.review_s if L.review_s is not None else (L.shown_s or span[1])
            changed, t = imgui.slider_float("##live-scrub", t, span[0], span[1], "%.2f s")
            if changed:
                run(v, "live", f"at {t}", now)
            runs = gnss.live_runs(L.feed.gnss, span)
            if runs:
                band(runs, span[1] - span[0])
            imgui.text_disabled(f"recorded {span[0]:.1f} to {span[1]:.1f} s in {L.folder}/")
        imgui.text(
            f"received {r.received}  drawn {r.frames_drawn}  lost on the way {r.missing}  "
            f"dropped by geofuse {r.skipped + r.late + r.overflow}  undecodable {r.undecodable}"
        )
        if L.pose_state and L.pose_state != "fresh":
            imgui.text_colored(
                colour(AMBER),
                "pose STALE: the telemetry is older than the frame by more than the buffer"
                if L.pose_state == "stale"
                else "no pose for this frame: drawn with the last one",
            )
        stale = L.pose_states.get("stale", 0)
        imgui.text(
            f"poses: stale {stale}, none {L.pose_states.get('none', 0)}, bad KLV sets {r.bad_klv}, reconnects {r.reconnects}"
        )
        if r.registration is not None:
            imgui.text_wrapped(r.registration.line())
        if r.mavlink is not None:
            lag = "estimating..." if r.mavlink.lag_s is None else f"{1000 * r.mavlink.lag_s:.0f} ms"
            imgui.text(f"MAVLink: the video lags the telemetry by {lag}")
    imgui.end()
