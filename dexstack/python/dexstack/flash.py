"""`dexflash`: flash a policy file (.dxpl) into a Jaco controller over CAN by CANopen program
download (CiA 302-3), on python-can and the `canopen` library.

    dexflash FILE.dxpl --node N [-i INTERFACE] [-c CHANNEL] [-b BITRATE] [-o KEY=VALUE ...]
    dexflash --info --node N ...
    dexflash --rollback --node N ...
    dexflash FILE.dxpl --dry-run --node N ...

The bus is `can.Bus(**kwargs)` with only the options given, so python-can's configuration
(environment, `~/can.conf`) fills in the rest. A flash: the identity (0x1018) is read; the file is
checked (magic, format version, header CRC-32, layout hash against the node's active policy in
0x2000:1 when it has one); the node is put into pre-operational (NMT); the file goes into 0x1F50:1
by SDO block download (segmented when the node does not take block transfers); 0x1F51:1 = 1
starts it; 0x1F56:1 must then equal the file's CRC-32; the next heartbeat shows the node alive.
The node's slots keep the previous policy running whatever happens to a download, and nothing is
started after a failed one. Every refusal is one line on stderr and a non-zero exit status:

    2 usage, 3 bad file, 4 the node does not answer, 5 SDO abort, 6 check failed (layout, CRC)
"""

from __future__ import annotations

import argparse
import logging
import struct
import sys
import time
import zlib
from dataclasses import dataclass
from pathlib import Path

EXIT_USAGE, EXIT_FILE, EXIT_TIMEOUT, EXIT_ABORT, EXIT_CHECK = 2, 3, 4, 5, 6

IDENTITY, PROGRAM_DATA, PROGRAM_CONTROL, PROGRAM_ID, FLASH_STATUS = (
    0x1018, 0x1F50, 0x1F51, 0x1F56, 0x1F57,
)
ACTIVE_POLICY, ENVELOPE_STATUS, DEVICE_TYPE = 0x2000, 0x2001, 0x1000
START, ROLL_BACK = 1, 0x80

MAGIC = b"DXPL"
HEADER_LEN, CRC_OFFSET = 24, 20
FORMAT_VERSIONS = (1, 2)
# Tasks in the order of `dex_policy::Task` (0x2000:4; 0xFF none).
TASKS = ("reach", "grasp", "stack-in-hand", "stack")
# Bits 1-7 of 0x1F57:1 (runtime/src/canopen/program.rs, FlashResult).
FLASH_RESULTS = {
    0: "ok", 1: "no program", 2: "format", 3: "refused", 4: "too large", 5: "aborted",
    6: "operational",
}
# What the controller means by the abort codes it answers with (docs/runtime.md, docs/sil.md).
ABORT_MEANINGS = {
    0x0504_0000: "SDO transfer timed out on the node",
    0x0504_0001: "command not understood by the node",
    0x0601_0001: "object is write only",
    0x0601_0002: "object is read only",
    0x0602_0000: "object does not exist on the node",
    0x0607_0010: "data length does not match",
    0x0607_0012: "file too large for a policy slot",
    0x0609_0011: "sub-index does not exist on the node",
    0x0609_0030: "value not supported",
    0x0800_0020: "the node refused the file (verification: format, CRC, layout, period or capacity)",
    0x0800_0022: "refused in the node's present state (operational)",
    0x0800_0024: "nothing to activate (no staged file, or no previous policy kept)",
}


class Refusal(Exception):
    """A refusal: one line for stderr and the exit status."""

    def __init__(self, message: str, status: int):
        super().__init__(message)
        self.status = status


@dataclass
class PolicyFile:
    """What dexflash checks of a .dxpl before sending it."""

    data: bytes
    version: int
    layout_hash: int
    header_crc: int

    @property
    def crc32(self) -> int:
        """CRC-32 of the whole file: what the node reports in 0x1F56:1 once it runs it."""
        return zlib.crc32(self.data)


def read_policy(path: Path) -> PolicyFile:
    """Reads and checks a policy file's header (policy-format/src/header.rs): magic, format
    version, flags, announced sizes and the file CRC-32."""
    try:
        data = path.read_bytes()
    except OSError as e:
        raise Refusal(f"cannot read {path}: {e.strerror or e}", EXIT_FILE) from e
    if len(data) < HEADER_LEN:
        raise Refusal(f"{path}: not a policy file ({len(data)} bytes, shorter than its header)", EXIT_FILE)
    if data[:4] != MAGIC:
        raise Refusal(f"{path}: not a policy file (magic {data[:4]!r}, expected {MAGIC!r})", EXIT_FILE)
    version, flags, layout, body_len, value_count, crc = struct.unpack_from("<HHIIII", data, 4)
    if version not in FORMAT_VERSIONS:
        raise Refusal(
            f"{path}: format version {version} not supported (supported: "
            f"{', '.join(map(str, FORMAT_VERSIONS))})", EXIT_FILE,
        )
    if flags != 0:
        raise Refusal(f"{path}: unknown header flags 0x{flags:04X}", EXIT_FILE)
    expected_len = -(-(HEADER_LEN + body_len) // 4) * 4 + 4 * value_count
    if len(data) != expected_len:
        raise Refusal(
            f"{path}: truncated or padded file ({len(data)} bytes, the header announces "
            f"{expected_len})", EXIT_FILE,
        )
    actual = zlib.crc32(data[HEADER_LEN:], zlib.crc32(data[:CRC_OFFSET]))
    if actual != crc:
        raise Refusal(
            f"{path}: corrupt file (CRC-32 0x{actual:08X}, the header says 0x{crc:08X})", EXIT_FILE
        )
    return PolicyFile(data, version, layout, crc)


def describe_abort(e) -> str:
    """An SDO abort as `0xCODE meaning`."""
    meaning = ABORT_MEANINGS.get(e.code) or type(e).CODES.get(e.code, "unknown abort code")
    return f"0x{e.code:08X} {meaning}"


def bus_kwargs(args) -> dict:
    """Only the bus options given on the command line (python-can's configuration fills in the
    rest)."""
    kwargs = {}
    if args.interface:
        kwargs["interface"] = args.interface
    if args.channel:
        kwargs["channel"] = args.channel
    if args.bitrate:
        kwargs["bitrate"] = args.bitrate
    for option in args.bus_option:
        key, sep, value = option.partition("=")
        if not sep or not key:
            raise Refusal(f"bad --bus-option {option!r}: expected KEY=VALUE", EXIT_USAGE)
        kwargs[key] = _option_value(value)
    return kwargs


def _option_value(text: str):
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    try:
        return int(text, 0)
    except ValueError:
        return text


class Session:
    """A canopen network on one python-can bus and the remote node."""

    def __init__(self, args):
        import can
        import canopen

        self.canopen = canopen
        try:
            bus = can.Bus(**bus_kwargs(args))
        except (can.CanError, OSError, ValueError, TypeError, ImportError) as e:
            raise Refusal(f"cannot open the CAN bus: {e}", EXIT_USAGE) from e
        self.network = canopen.Network(bus)
        self.network.connect()
        self.node = canopen.RemoteNode(args.node, canopen.ObjectDictionary())
        self.network.add_node(self.node)
        self.node.sdo.RESPONSE_TIMEOUT = args.timeout
        self.node.sdo.MAX_RETRIES = 1  # one request, no retry (canopen counts tries)
        self.node_id = args.node
        self.timeout = args.timeout

    def close(self):
        self.network.disconnect()

    def upload_u(self, index: int, sub: int, what: str) -> int:
        return int.from_bytes(self.call(lambda: self.node.sdo.upload(index, sub), what), "little")

    def call(self, fn, what: str):
        """Runs an SDO exchange; an abort or silence becomes a Refusal naming `what`."""
        from canopen.sdo import SdoAbortedError, SdoCommunicationError

        try:
            return fn()
        except SdoAbortedError as e:
            raise Refusal(f"node {self.node_id}: {what} refused: {describe_abort(e)}", EXIT_ABORT) from e
        except SdoCommunicationError as e:
            raise Refusal(
                f"node {self.node_id} does not answer ({what}: no SDO response within "
                f"{self.timeout:g} s)", EXIT_TIMEOUT,
            ) from e

    def identity(self) -> dict:
        return {
            name: self.upload_u(IDENTITY, sub, "reading the identity 0x1018")
            for sub, name in ((1, "vendor"), (2, "product"), (3, "revision"), (4, "serial"))
        }

    def policy(self) -> dict:
        """The active policy (0x2000, 0x1F56)."""
        u = lambda index, sub: self.upload_u(index, sub, f"reading 0x{index:04X}:{sub}")  # noqa: E731
        return {
            "layout_hash": u(ACTIVE_POLICY, 1),
            "format_version": u(ACTIVE_POLICY, 2),
            "file_crc": u(ACTIVE_POLICY, 3),
            "task": u(ACTIVE_POLICY, 4),
            "generation": u(ACTIVE_POLICY, 5),
            "program_id": u(PROGRAM_ID, 1),
        }

    def flash_status(self) -> dict:
        word = self.upload_u(FLASH_STATUS, 1, "reading the flash status 0x1F57")
        result = (word >> 1) & 0x7F
        return {
            "word": word,
            "downloading": bool(word & 1),
            "result": FLASH_RESULTS.get(result, f"unknown ({result})"),
            "staged": bool(word & 0x100),
        }

    def to_preoperational(self) -> None:
        """NMT enter pre-operational, then wait until the controller has left operational
        (0x1F51:1 reads 1 while it is operational: it leaves at its next control cycle)."""
        self.node.nmt.state = "PRE-OPERATIONAL"
        deadline = time.monotonic() + self.timeout
        while self.upload_u(PROGRAM_CONTROL, 1, "reading the program control 0x1F51") != 0:
            if time.monotonic() > deadline:
                raise Refusal(
                    f"node {self.node_id} stays operational after NMT pre-operational", EXIT_CHECK
                )
            time.sleep(0.02)

    def heartbeat(self) -> str:
        try:
            return self.node.nmt.wait_for_heartbeat(max(self.timeout, 1.5))
        except self.canopen.nmt.NmtError as e:
            raise Refusal(
                f"node {self.node_id} sends no heartbeat within {max(self.timeout, 1.5):g} s", EXIT_TIMEOUT
            ) from e


def describe_policy(p: dict) -> str:
    if p["program_id"] == 0:
        return "no policy"
    task = TASKS[p["task"]] if p["task"] < len(TASKS) else ("none" if p["task"] == 0xFF else str(p["task"]))
    return (
        f"policy CRC-32 0x{p['program_id']:08X}, format v{p['format_version']}, layout hash "
        f"0x{p['layout_hash']:08X}, task {task}, slot generation {p['generation']}"
    )


def describe_identity(i: dict) -> str:
    return (
        f"vendor 0x{i['vendor']:08X}, product 0x{i['product']:08X}, revision "
        f"{i['revision'] >> 16}.{i['revision'] & 0xFFFF}, serial 0x{i['serial']:08X}"
    )


def check_layout(s: Session, policy: PolicyFile, path: Path, active: dict, out) -> None:
    """The file's layout hash against the node's active policy's (0x2000:1). A node without a
    policy has no layout to compare: the node checks the layout itself when the download ends."""
    if active["program_id"] == 0:
        print(
            f"note: node {s.node_id} runs no policy, so its layout hash is unknown here; the node "
            "checks the layout when the download ends", file=out,
        )
        return
    if active["layout_hash"] != policy.layout_hash:
        raise Refusal(
            f"{path}: layout mismatch (file layout hash 0x{policy.layout_hash:08X}, node 0x"
            f"{active['layout_hash']:08X})", EXIT_CHECK,
        )


class Progress:
    """tqdm when it is installed, else a simple bar on stderr."""

    def __init__(self, total: int, quiet: bool):
        self.total, self.done, self.quiet, self.bar = total, 0, quiet, None
        if quiet:
            return
        try:
            from tqdm import tqdm

            self.bar = tqdm(total=total, unit="B", unit_scale=True, desc="0x1F50", file=sys.stderr)
        except ImportError:
            self.bar = None

    def update(self, n: int):
        self.done += n
        if self.quiet:
            return
        if self.bar is not None:
            self.bar.update(n)
        else:
            filled = 40 * self.done // max(self.total, 1)
            sys.stderr.write(f"\r0x1F50 [{'#' * filled}{'.' * (40 - filled)}] {self.done}/{self.total} B")
            sys.stderr.flush()

    def close(self):
        if self.bar is not None:
            self.bar.close()
        elif not self.quiet:
            sys.stderr.write("\n")


def download(s: Session, data: bytes, quiet: bool) -> str:
    """0x1F50:1 by block download (segmented when the node refuses block transfers); returns
    which transfer was used."""
    from canopen.sdo import SdoAbortedError

    chunk = 7 * 127

    def run(block: bool):
        progress = Progress(len(data), quiet)
        try:
            with s.node.sdo.open(PROGRAM_DATA, 1, "wb", block_transfer=block, size=len(data)) as f:
                for k in range(0, len(data), chunk):
                    f.write(data[k : k + chunk])
                    progress.update(len(data[k : k + chunk]))
        finally:
            progress.close()

    try:
        s.call(lambda: run(True), "program download 0x1F50:1")
        return "block"
    except Refusal as e:
        cause = e.__cause__
        if isinstance(cause, SdoAbortedError) and cause.code == 0x0504_0001:
            s.call(lambda: run(False), "program download 0x1F50:1 (segmented)")
            return "segmented"
        raise


def flash(s: Session, args, out) -> None:
    path = Path(args.file)
    policy = read_policy(path)
    identity = s.identity()
    print(f"node {s.node_id}: {describe_identity(identity)}", file=out)
    active = s.policy()
    print(f"node {s.node_id} runs: {describe_policy(active)}", file=out)
    check_layout(s, policy, path, active, out)
    print(
        f"{path}: format v{policy.version}, {len(policy.data)} bytes, CRC-32 0x{policy.crc32:08X}, "
        f"layout hash 0x{policy.layout_hash:08X}: ok", file=out,
    )
    if args.dry_run:
        print("dry run: nothing sent", file=out)
        return
    s.to_preoperational()
    try:
        how = download(s, policy.data, args.quiet)
    except Refusal as e:
        try:
            status = s.flash_status()
            e.args = (f"{e.args[0]} (flash status: {status['result']})",)
        except Refusal:
            pass
        raise
    print(f"downloaded {len(policy.data)} bytes ({how} transfer)", file=out)
    s.call(lambda: s.node.sdo.download(PROGRAM_CONTROL, 1, bytes([START])), "start 0x1F51:1")
    now = s.upload_u(PROGRAM_ID, 1, "reading the program id 0x1F56")
    if now != policy.crc32:
        raise Refusal(
            f"node {s.node_id} runs CRC-32 0x{now:08X} after the start, not the file's 0x{policy.crc32:08X}",
            EXIT_CHECK,
        )
    state = s.heartbeat()
    if args.start:
        s.node.nmt.state = "OPERATIONAL"
        state = "OPERATIONAL"
    print(f"node {s.node_id} ({state}) runs: {describe_policy(s.policy())}", file=out)


def info(s: Session, out) -> None:
    device_type = s.upload_u(DEVICE_TYPE, 0, "reading the device type 0x1000")
    identity = s.identity()
    status = s.flash_status()
    active = s.policy()
    envelope = s.upload_u(ENVELOPE_STATUS, 0, "reading the envelope status 0x2001")
    state = s.heartbeat()
    print(f"node {s.node_id}: {state}, device type 0x{device_type:08X}", file=out)
    print(f"identity: {describe_identity(identity)}", file=out)
    print(f"program id (0x1F56:1): 0x{active['program_id']:08X}", file=out)
    print(
        f"flash status (0x1F57:1): 0x{status['word']:08X}: last result {status['result']}, "
        f"{'a file staged' if status['staged'] else 'nothing staged'}"
        f"{', download in progress' if status['downloading'] else ''}", file=out,
    )
    print(f"active policy (0x2000): {describe_policy(active)}", file=out)
    print(f"envelope status (0x2001): 0x{envelope:02X}", file=out)


def rollback(s: Session, out) -> None:
    s.identity()
    before = s.policy()
    print(f"node {s.node_id} runs: {describe_policy(before)}", file=out)
    s.to_preoperational()
    s.call(lambda: s.node.sdo.download(PROGRAM_CONTROL, 1, bytes([ROLL_BACK])), "roll-back 0x1F51:1")
    state = s.heartbeat()
    print(f"rolled back; node {s.node_id} ({state}) runs: {describe_policy(s.policy())}", file=out)


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="dexflash",
        description="Flash a policy file into a Jaco controller by CANopen program download (0x1F50).",
    )
    p.add_argument("file", nargs="?", help="the policy file (.dxpl)")
    p.add_argument("-n", "--node", type=lambda t: int(t, 0), required=True, help="node id (1-127)")
    p.add_argument("-i", "--interface", help="python-can interface (socketcand, socketcan, pcan, ...)")
    p.add_argument("-c", "--channel", help="python-can channel")
    p.add_argument("-b", "--bitrate", type=int, help="bit rate")
    p.add_argument(
        "-o", "--bus-option", action="append", default=[], metavar="KEY=VALUE",
        help="another can.Bus keyword (e.g. host=127.0.0.1, port=29536)",
    )
    p.add_argument("--timeout", type=float, default=2.0, help="SDO response timeout, s (default 2)")
    what = p.add_mutually_exclusive_group()
    what.add_argument("--info", action="store_true", help="what the node runs; nothing is changed")
    what.add_argument("--rollback", action="store_true", help="make the previous policy active again")
    what.add_argument("--dry-run", action="store_true", help="all checks, no download")
    p.add_argument("--start", action="store_true", help="NMT start the node after a successful flash")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    return p


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    out = sys.stdout
    if not 1 <= args.node <= 127:
        print(f"dexflash: node id {args.node} out of range 1-127", file=sys.stderr)
        return EXIT_USAGE
    if not (args.info or args.rollback) and args.file is None:
        print("dexflash: a policy file is needed (or --info / --rollback)", file=sys.stderr)
        return EXIT_USAGE
    if args.timeout <= 0:
        print("dexflash: --timeout must be positive", file=sys.stderr)
        return EXIT_USAGE
    try:
        import can  # noqa: F401
        import canopen  # noqa: F401
    except ImportError as e:
        print(f"dexflash: needs python-can and canopen ({e}); pip install 'dexstack[flash]'", file=sys.stderr)
        return EXIT_USAGE
    # The library logs what dexflash reports itself (timeouts, its own aborts): keep stderr to
    # dexflash's one line.
    logging.getLogger("canopen").addHandler(logging.NullHandler())
    session = None
    try:
        if args.file is not None and not (args.info or args.rollback):
            read_policy(Path(args.file))  # a bad file is refused before the bus is opened
        session = Session(args)
        if args.info:
            info(session, out)
        elif args.rollback:
            rollback(session, out)
        else:
            flash(session, args, out)
        return 0
    except Refusal as e:
        print(f"dexflash: {e}", file=sys.stderr)
        return e.status
    finally:
        if session is not None:
            session.close()


if __name__ == "__main__":
    sys.exit(main())
