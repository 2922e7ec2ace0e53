"""Recording layer: canonical CDR, rosbag2-layout MCAP sink, and readers (no rclpy needed).

Public names:
    McapSink            -- the sink the simulator calls (sim-time stamps, small flushed chunks)
    encode, decode      -- canonical little-endian CDR for any ROS 2 .msg type
    full_text, get_msgdef, canonical_name -- .msg lookup/parsing and ros2msg schema text
    read_messages, read_raw_messages, summarize -- read recordings, also truncated ones
"""
from .cdr import decode, encode
from .mcap_sink import METADATA_NAME, McapSink, qos_yaml
from .msgdefs import canonical_name, full_text, get_msgdef
from .reader import read_messages, read_raw_messages, summarize

__all__ = [
    'McapSink', 'METADATA_NAME', 'qos_yaml',
    'encode', 'decode',
    'canonical_name', 'full_text', 'get_msgdef',
    'read_messages', 'read_raw_messages', 'summarize',
]
