"""Type stub of the optional C accelerator of the rosbag2 sqlite3 reader (see _db3pages.c)."""

from typing_extensions import Buffer

def scan(
    file: Buffer,
    page_size: int,
    table_root: int,
    index_root: int,
    ids: Buffer,
    pick: Buffer,
    ngroups: int,
    release: bool = False,
    /,
) -> tuple[bytearray, bytearray, bytearray, bytearray, bytearray, tuple[Buffer, ...]] | str:
    """Read rosbag2's messages table and its timestamp index from the pages of ``file``.

    Returns (stats, counts, stamps, offsets, lengths, payloads: one buffer per group) or a
    str naming why it declines.
    """
