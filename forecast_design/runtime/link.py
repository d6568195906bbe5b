"""The serial link: the only module of forecast_design that touches pyserial."""

from __future__ import annotations

import time

from ..errors import ForecastError

try:   # pyserial's flush() on a POSIX port calls tcdrain, whose failure is termios.error, not OSError
    from termios import error as _TermiosError
except ImportError:   # not a POSIX system
    class _TermiosError(Exception):
        """Never raised where termios does not exist."""

__all__ = ["BoardError", "LinkError", "Link"]


class BoardError(ForecastError, RuntimeError):
    """The board (or emulator) answered wrongly, refused a command, or a run lost data.

    Parameters
    ----------
    message : str
        One line: what failed and what was expected.
    summary : dict, optional
        The run summary at the time of the error (samples, lost, corrupt_frames, resyncs).
    saved : str, optional
        The experiment written with what was received, if any.
    """

    def __init__(self, message: str, *, summary: dict | None = None, saved: str | None = None):
        super().__init__(message)
        self.summary = summary or {}
        self.saved = saved


class LinkError(BoardError):
    """The serial port failed, closed, or went silent (a disconnect)."""


class Link:
    """A byte pipe over any pyserial URL: a device path, ``loop://``, or a pty path.

    Parameters
    ----------
    port : str
        Device path or pyserial URL (``serial.serial_for_url``).
    baudrate : int
        UART rate [bit/s]; ignored by ptys and ``loop://``.
    timeout : float
        Longest single read wait [s].

    Raises
    ------
    LinkError
        If the port cannot be opened.
    """

    def __init__(self, port: str, *, baudrate: int = 2_000_000, timeout: float = 0.05):
        import serial

        self.port = port
        try:
            self._serial = serial.serial_for_url(port, baudrate=baudrate, timeout=timeout,
                                                 write_timeout=2.0)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LinkError(f"{port}: cannot open serial port: {exc}") from None

    def write(self, data: bytes) -> None:
        """Send bytes; LinkError on a failed or timed-out write."""
        import serial

        try:
            self._serial.write(data)
            self._serial.flush()
        except (serial.SerialException, OSError, _TermiosError) as exc:
            raise LinkError(f"{self.port}: write failed (disconnected?): {exc}") from None

    def read(self, max_bytes: int = 4096, timeout: float | None = None) -> bytes:
        """Read what is available, waiting at most ``timeout`` [s] for the first byte.

        Parameters
        ----------
        max_bytes : int
            Upper bound on the bytes returned.
        timeout : float, optional
            Wait [s]; the port's default when omitted.

        Returns
        -------
        bytes
            Possibly empty when nothing arrived in time.

        Raises
        ------
        LinkError
            If the port reports an error (device unplugged, pty closed).
        """
        import serial

        try:
            if timeout is not None:
                self._serial.timeout = timeout
            waiting = self._serial.in_waiting
            return self._serial.read(min(max(waiting, 1), max_bytes))
        except (serial.SerialException, OSError, _TermiosError) as exc:
            raise LinkError(f"{self.port}: read failed (disconnected?): {exc}") from None

    def drain(self, quiet_s: float = 0.05, limit_s: float = 1.0) -> int:
        """Discard input until the line has been quiet for ``quiet_s`` [s]; return bytes discarded."""
        n = 0
        deadline = time.monotonic() + limit_s
        while time.monotonic() < deadline:
            chunk = self.read(timeout=quiet_s)
            if not chunk:
                break
            n += len(chunk)
        return n

    def close(self) -> None:
        """Close the port (idempotent)."""
        try:
            self._serial.close()
        except Exception:  # noqa: BLE001 - closing a vanished device must not mask the real error
            pass

    def __enter__(self) -> "Link":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
