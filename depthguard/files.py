"""Reading and writing files as depthguard does, for code built on it (the lab, a user's tools).

- Reading: a file is checked before it is opened (a regular file, at most ``max_bytes``), then read whole;
  YAML is parsed with a safe loader that refuses aliases, duplicate keys, tags and deep nesting
  (:func:`read_bytes`, :func:`read_text`, :func:`read_yaml`, :func:`load_yaml`, :func:`load_json`).
- Writing: a file is written whole or not at all, to a temporary file beside it and renamed
  (:func:`atomic_write`, :func:`write_whole`; a folder: :func:`atomic_folder`).

Each raises a :class:`depthguard.DepthguardError` naming the file.
"""

from depthguard._files import (
    atomic_folder,
    atomic_write,
    check_regular_file,
    load_json,
    load_yaml,
    read_bytes,
    read_text,
    read_yaml,
    write_whole,
)

__all__ = ["atomic_folder", "atomic_write", "check_regular_file", "load_json", "load_yaml", "read_bytes", "read_text",
           "read_yaml", "write_whole"]
