"""Answers to what a ground station asks of our component: PING, commands, parameters, FTP.

Parameter requests go to ``parameters.ParameterServer`` and FILE_TRANSFER_PROTOCOL to ``ftp``
(a NAK). Commands handled (as COMMAND_LONG or COMMAND_INT, each answered with COMMAND_ACK before
any message):

- ``MAV_CMD_SET_MESSAGE_INTERVAL`` for the streams of ``StreamRates`` (param1 message id, param2
  interval in µs, -1 stop, 0 default): ACCEPTED, or DENIED for another message id or a bad interval.
- ``MAV_CMD_REQUEST_MESSAGE`` (param1 message id): whatever ``request_message`` produces; MESSAGE_INTERVAL
  (param2 = the message id asked about) is answered here. DENIED when the message is not
  available from us, TEMPORARILY_REJECTED when it is but has nothing to say right now.
- ``MAV_CMD_GET_MESSAGE_INTERVAL`` (deprecated, still sent by ground stations): as above.
- ``MAV_CMD_GET_HOME_POSITION`` (deprecated, still sent): as REQUEST_MESSAGE(HOME_POSITION).
- other commands: UNSUPPORTED when aimed at us, that is at our system (any component: ground
  stations send to component 0 and wait for an ACK) or at our component; ignored when broadcast to
  every system and component (the component they are meant for answers them).

A command is ours when its target system is ours or 0 (broadcast) and its target component is
ours or 0; anything else, and anything we sent ourselves, is ignored. A PING with target 0/0 is a
request and is answered to its sender; a PING with a target is a reply to someone and is ignored.
What reaches here has passed the sink's checks: sent by an admitted peer (``peers``), and with
signing on, correctly signed and not a replay (``verify``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

from .ftp import ftp_reply
from .parameters import ParameterServer
from .streams import StreamRates

__all__ = ["CommandHandler"]

log = logging.getLogger(__name__)

MESSAGE_INTERVAL_ID = 244
HOME_POSITION_ID = 242


class CommandHandler:
    """Turns one received message into the replies to send (possibly none).

    Parameters
    ----------
    dialect : the generated dialect module.
    sysid, compid : our system and component ids.
    rates : the stream intervals that SET_MESSAGE_INTERVAL changes.
    request_message : ``f(message_id) -> list of messages`` for MAV_CMD_REQUEST_MESSAGE, or None
        when we do not produce that message.
    default_interval_us : ``f(message_id) -> int``, the interval reported by MESSAGE_INTERVAL for a
        stream at its default rate (the measured update interval; 0 when unknown).
    parameters : the read-only parameters served (None: parameter requests are not answered).
    """

    def __init__(
        self,
        dialect,
        sysid: int,
        compid: int,
        rates: StreamRates,
        request_message: Callable[[int], list | None],
        default_interval_us: Callable[[int], int],
        parameters: ParameterServer | None = None,
    ) -> None:
        self._d = dialect
        self._sysid = sysid
        self._compid = compid
        self._rates = rates
        self._request_message = request_message
        self._default_interval_us = default_interval_us
        self._parameters = parameters

    def handle(self, msg) -> list:
        """Replies to ``msg`` (a decoded message of the dialect), in sending order."""
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if src == (self._sysid, self._compid):
            return []
        kind = msg.get_type()
        if kind == "PING":
            return self._ping(msg, src)
        if kind == "FILE_TRANSFER_PROTOCOL":
            reply = ftp_reply(self._d, msg, self._sysid, self._compid)
            return [] if reply is None else [reply]
        if self._parameters is not None:
            replies = self._parameters.handle(msg)
            if replies is not None:
                return replies
        if kind == "COMMAND_LONG":
            params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        elif kind == "COMMAND_INT":
            params = (msg.param1, msg.param2, msg.param3, msg.param4, float(msg.x), float(msg.y), msg.z)
        else:
            return []
        if msg.target_system not in (0, self._sysid) or msg.target_component not in (0, self._compid):
            return []
        direct = msg.target_system == self._sysid or msg.target_component == self._compid
        return self._command(msg.command, params, src, direct=direct)

    def _ping(self, msg, src: tuple[int, int]) -> list:
        if msg.target_system != 0 or msg.target_component != 0:
            return []
        return [self._d.MAVLink_ping_message(msg.time_usec, msg.seq, src[0], src[1])]

    def _ack(self, command: int, result: int, src: tuple[int, int]):
        return self._d.MAVLink_command_ack_message(command, result, 0, 0, src[0], src[1])

    def _command(self, command: int, params: tuple, src: tuple[int, int], direct: bool) -> list:
        d = self._d
        if command == d.MAV_CMD_SET_MESSAGE_INTERVAL:
            return [self._ack(command, self._set_interval(params, src), src)]
        if command == d.MAV_CMD_GET_MESSAGE_INTERVAL:
            return self._message_interval_reply(command, params[0], src)
        if command in (d.MAV_CMD_REQUEST_MESSAGE, d.MAV_CMD_GET_HOME_POSITION):
            message_id = HOME_POSITION_ID if command == d.MAV_CMD_GET_HOME_POSITION else _as_int(params[0])
            if message_id == MESSAGE_INTERVAL_ID:
                return self._message_interval_reply(command, params[1], src)
            replies = None if message_id is None else self._request_message(message_id)
            if replies is None:
                return [self._ack(command, d.MAV_RESULT_DENIED, src)]
            if not replies:
                return [self._ack(command, d.MAV_RESULT_TEMPORARILY_REJECTED, src)]
            log.debug("system %d/%d requested message %d", *src, message_id)
            return [self._ack(command, d.MAV_RESULT_ACCEPTED, src), *replies]
        if direct:
            return [self._ack(command, d.MAV_RESULT_UNSUPPORTED, src)]
        return []

    def _set_interval(self, params: tuple, src: tuple[int, int]) -> int:
        d = self._d
        message_id, interval = _as_int(params[0]), _as_int(params[1])
        if message_id is None or interval is None or interval < -1 or not self._rates.supports(message_id):
            log.info(
                "system %d/%d asked for message %s at interval %s us: refused (streams: 510, 511, 246)",
                *src,
                params[0],
                params[1],
            )
            return d.MAV_RESULT_DENIED
        self._rates.set_interval(message_id, interval)
        what = {-1: "disabled", 0: "default (every track update)"}.get(interval, f"{interval} us")
        log.info("system %d/%d set the interval of message %d to %s", *src, message_id, what)
        return d.MAV_RESULT_ACCEPTED

    def _message_interval_reply(self, command: int, asked: float, src: tuple[int, int]) -> list:
        message_id = _as_int(asked)
        if message_id is None:
            return [self._ack(command, self._d.MAV_RESULT_DENIED, src)]
        if self._rates.supports(message_id):
            interval = self._rates.interval_us(message_id)
            if interval == 0:
                interval = self._default_interval_us(message_id)
        else:
            interval = 0  # "not available" in MESSAGE_INTERVAL's terms
        reply = self._d.MAVLink_message_interval_message(message_id, interval)
        return [self._ack(command, self._d.MAV_RESULT_ACCEPTED, src), reply]


def _as_int(value: float) -> int | None:
    """A command parameter that must hold an integer (message id, interval), or None."""
    if value is None or not math.isfinite(value) or value != round(value):
        return None
    return round(value)
