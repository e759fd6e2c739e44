"""The lockstep channel (the paper's GZUAVCHANNEL): a sans-I/O tick machine, its watchdog and its I/O shell.

``machine`` holds the tick (events in, actions out), ``watchdog`` the deadlines on an injected clock,
``shell`` the sockets and the handshake around them; see docs/channel.md.
"""

from harness.channel.config import ChannelConfig, Fault, MissionExit
from harness.channel.shell import Channel, connect_child_socket

__all__ = ["Channel", "ChannelConfig", "Fault", "MissionExit", "connect_child_socket"]
