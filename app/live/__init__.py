"""Live feeds: a drone's downlink (MPEG-TS with MISB KLV over udp/rtp/rtsp/srt) received on a
thread, recorded before anything else reads it, drawn through a jitter buffer with each frame's own
pose (forward-only), and the figures of what arrived, was drawn and was lost."""
