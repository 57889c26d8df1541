"""The one exception tree of the protocol layer.

Everything the focas package raises derives from FocasError, so callers can catch protocol trouble
without catching programming errors. CNC return codes (EW_*) keep their number, their fwlib32.h name
and the function that answered them.
"""

from __future__ import annotations

# Every return code of fwlib32.h by number. Positive codes come from the CNC (on the wire, per
# subpacket); negative ones are library-side in the vendor DLL and are reused here for our own
# client-side conditions where the meaning matches (EW_SOCKET, EW_PROTOCOL, EW_BUSY ...).
EW_CODES: dict[int, str] = {
    -17: "EW_PROTOCOL",
    -16: "EW_SOCKET",
    -15: "EW_NODLL",
    -14: "EW_INIERR",
    -13: "EW_ITLOW",
    -12: "EW_ITHIGHT",
    -11: "EW_BUS",
    -10: "EW_SYSTEM2",
    -9: "EW_HSSB",
    -8: "EW_HANDLE",
    -7: "EW_VERSION",
    -6: "EW_UNEXP",
    -5: "EW_SYSTEM",
    -4: "EW_PARITY",
    -3: "EW_MMCSYS",
    -2: "EW_RESET",
    -1: "EW_BUSY",
    0: "EW_OK",
    1: "EW_FUNC",  # also EW_NOPMC
    2: "EW_LENGTH",
    3: "EW_NUMBER",  # also EW_RANGE
    4: "EW_ATTRIB",  # also EW_TYPE
    5: "EW_DATA",
    6: "EW_NOOPT",
    7: "EW_PROT",
    8: "EW_OVRFLOW",
    9: "EW_PARAM",
    10: "EW_BUFFER",
    11: "EW_PATH",
    12: "EW_MODE",
    13: "EW_REJECT",
    14: "EW_DTSRVR",
    15: "EW_ALARM",
    16: "EW_STOP",
    17: "EW_PASSWD",
    18: "EW_PMC",
    19: "EW_PMCHANDLE",
    20: "EW_RD_OVWSTP",
    21: "EW_RD_RSTFIN",
}
EW_ALIASES: dict[str, int] = {"EW_NOPMC": 1, "EW_RANGE": 3, "EW_TYPE": 4}
EW_BY_NAME: dict[str, int] = {name: code for code, name in EW_CODES.items()} | EW_ALIASES

EW_OK = 0
EW_FUNC = 1
EW_LENGTH = 2
EW_NUMBER = 3
EW_ATTRIB = 4
EW_DATA = 5
EW_NOOPT = 6
EW_PROT = 7
EW_PATH = 11
EW_MODE = 12
EW_REJECT = 13
EW_PASSWD = 17
EW_BUSY = -1
EW_UNEXP = -6  # "unexpected error"
EW_SOCKET = -16


def ew_name(code: int) -> str:
    """The fwlib32.h name of a return code, or EW_<code> for one the header does not list."""
    return EW_CODES.get(code, f"EW_{code}")


class FocasError(Exception):
    """Root of every error raised by edge.focas."""


class ProtocolError(FocasError):
    """The peer sent bytes that do not follow the protocol (bad sync, impossible length, wrong echo...)."""


class FocasTimeout(FocasError):
    """A request got no complete answer within its deadline; the session is reset."""


class ConnectionLost(FocasError):
    """The TCP session closed, was refused, or could not be reached."""


class NotSupported(FocasError):
    """This transport or control cannot do the operation (no public wire code, EW_FUNC, EW_NOOPT)."""

    def __init__(self, operation: str, reason: str) -> None:
        self.operation = operation
        self.reason = reason
        super().__init__(f"{operation}: not supported: {reason}")


class CncError(FocasError):
    """The CNC answered a function with a non-zero EW_* return code."""

    def __init__(self, code: int, function: str, detail: int = 0, message: str = "") -> None:
        self.code = code
        self.name = ew_name(code)
        self.function = function
        self.detail = detail
        text = f"{function}: CNC returned {self.name} ({code})"
        if detail:
            text += f", detail {detail}"
        if message:
            text += f": {message}"
        # Not super(): in FunctionNotAvailable the next class in the MRO is NotSupported(operation, reason).
        FocasError.__init__(self, text)


class FunctionNotAvailable(CncError, NotSupported):
    """EW_FUNC / EW_NOOPT: this control does not have the function (or the option for it)."""

    def __init__(self, code: int, function: str, detail: int = 0, message: str = "") -> None:
        CncError.__init__(self, code, function, detail, message)
        self.operation = function
        self.reason = self.name


class AccessDenied(CncError):
    """EW_PASSWD: parameter-write switch off, CNC not in MDI, or protected data."""


class OutOfRange(CncError):
    """EW_NUMBER / EW_ATTRIB: number, address or type outside what the control has."""


class LengthError(CncError):
    """EW_LENGTH: a data block too long (e.g. a PMC write over 32 bytes) or the wrong size."""


class Busy(CncError):
    """EW_BUSY / EW_REJECT / EW_MODE: the control cannot take the request now."""


_CLASS_BY_CODE: dict[int, type[CncError]] = {
    1: FunctionNotAvailable,
    6: FunctionNotAvailable,
    17: AccessDenied,
    3: OutOfRange,
    4: OutOfRange,
    2: LengthError,
    -1: Busy,
    12: Busy,
    13: Busy,
}


def cnc_error(code: int, function: str, detail: int = 0, message: str = "") -> CncError:
    """The typed exception for a CNC return code (a plain CncError where no finer type applies)."""
    cls = _CLASS_BY_CODE.get(code, CncError)
    return cls(code, function, detail, message)
