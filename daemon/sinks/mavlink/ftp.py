"""MAVLink FTP (FILE_TRANSFER_PROTOCOL): DroneKey has no files, and says so at once.

Ground stations try MAVLink FTP first for parameters (MAVProxy gets ``@PARAM/param.pck``) and
component metadata (QGroundControl); a component that stays silent is retried until a timeout.
Every request aimed at our component is answered with a NAK, as the FTP spec describes:

- the reply's header repeats the session, ``req_opcode`` is the request's opcode, ``seq_number`` is
  the request's plus one, ``opcode`` is NAK (129), ``size`` 1 and ``data[0]`` the error code;
- the error code says why: ``FileNotFound`` (10) for anything that opens, lists, checks or removes a
  path, ``FileProtected`` (9) for anything that would create or write, ``InvalidSession`` (4) for
  reads, writes and terminations of a session (none is ever opened), ``UnknownCommand`` (7) for
  opcodes we do not know. ``ResetSessions`` (2) is ACKed: there is nothing to reset.

Payload layout (little-endian, 251 bytes): seq_number uint16, session uint8, opcode uint8, size
uint8, req_opcode uint8, burst_complete uint8, padding uint8, offset uint32, data[239].
"""

from __future__ import annotations

import struct

__all__ = ["ACK", "NAK", "ftp_reply", "parse_header"]

_HEADER = struct.Struct("<HBBBBBBI")
_PAYLOAD_LEN = 251

ACK, NAK = 128, 129

# Error codes of the FTP spec.
ERR_INVALID_SESSION = 4
ERR_UNKNOWN_COMMAND = 7
ERR_FILE_PROTECTED = 9
ERR_FILE_NOT_FOUND = 10

# Opcodes, grouped by the error they draw.
_RESET_SESSIONS = 2
_SESSION_OPS = {1, 5, 7, 15}  # TerminateSession, ReadFile, WriteFile, BurstReadFile
_PATH_OPS = {3, 4, 8, 10, 12, 13, 14}  # List, OpenRO, Remove, RemoveDir, Truncate, Rename, CRC32
_CREATE_OPS = {6, 9, 11}  # CreateFile, CreateDirectory, OpenFileWO


def parse_header(payload) -> tuple[int, int, int, int, int, int, int]:
    """(seq_number, session, opcode, size, req_opcode, burst_complete, offset) of an FTP payload."""
    seq, session, opcode, size, req_opcode, burst, _pad, offset = _HEADER.unpack_from(bytes(payload[:12]))
    return seq, session, opcode, size, req_opcode, burst, offset


def _error_for(opcode: int) -> int | None:
    """The NAK error code for a request opcode; None for ResetSessions (ACKed)."""
    if opcode == _RESET_SESSIONS:
        return None
    if opcode in _SESSION_OPS:
        return ERR_INVALID_SESSION
    if opcode in _PATH_OPS:
        return ERR_FILE_NOT_FOUND
    if opcode in _CREATE_OPS:
        return ERR_FILE_PROTECTED
    return ERR_UNKNOWN_COMMAND


def ftp_reply(dialect, msg, sysid: int, compid: int):
    """The reply to a FILE_TRANSFER_PROTOCOL message aimed at us, or None (not ours, or not a request).

    ``msg`` is ours when its target system is ours or 0 and its target component ours or 0. Replies
    (opcode ACK or NAK) are never answered, so two components cannot NAK each other forever.
    """
    if msg.target_system not in (0, sysid) or msg.target_component not in (0, compid):
        return None
    payload = bytes(msg.payload)
    if len(payload) < _HEADER.size:
        return None
    seq, session, opcode, _size, _req, _burst, _offset = parse_header(payload)
    if opcode in (ACK, NAK):
        return None
    error = _error_for(opcode)
    reply_opcode, data = (ACK, b"") if error is None else (NAK, bytes([error]))
    header = _HEADER.pack((seq + 1) & 0xFFFF, session, reply_opcode, len(data), opcode, 0, 0, 0)
    body = (header + data).ljust(_PAYLOAD_LEN, b"\0")
    return dialect.MAVLink_file_transfer_protocol_message(
        0, msg.get_srcSystem(), msg.get_srcComponent(), list(body)
    )
