#!/usr/bin/env python3
"""fake_modem.py - a Hayes-compatible telephone modem on a pseudo-terminal, for tests.

Written from the Hayes AT command conventions (not from the Rust code that dials it),
Python 3.9+ standard library only. It opens DTE (one end of a socat pseudo-terminal
pair: the other end is the computer's "serial port"), sets it raw, and behaves as a
modem whose telephone line is simulated by the options:

  python3 fake_modem.py DTE [--connect NUMBER=PTYPATH]... [--busy NUMBER]...
      [--no-carrier NUMBER]... [--no-answer NUMBER]... [--no-dialtone] [--silent]
      [--ring-seconds 0.5] [--no-answer-seconds 2.0] [--guard 1.0]
      [--drop-after SECONDS] [--run-for SECONDS]

Command mode (the state at start, factory defaults E1 V1 Q0 X4):
  * Characters are collected up to S3 (CR); S5 (backspace) and DEL erase one. With E1
    every character is echoed as it arrives. Anything before "AT" (any case) on a
    line is skipped, as a modem hunting for the attention code does; a line without
    "AT" gets no answer. "A/" repeats the last command line at once.
  * Commands after AT, any number on one line: E0/E1 echo, V0/V1 verbal or numeric
    results, Q0/Q1 quiet, X0..X4 result set, Z reset, I info, H/H0 hang up, H1,
    O back online (in a call), A answer (there is no call to answer: NO CARRIER),
    S<n>=<v> and S<n>? registers, &<letter>[n], %<letter>[n], \\<letter>[n], and
    B C F L M N P T W Y with an optional number (accepted, no effect). Any other
    letter, or a value out of range, is an ERROR (the rest of the line is dropped).
  * D<dial string> dials: the number matched against the options is the dial string
    with everything but digits, '+', '*' and '#' removed (so "T555-1234" is 5551234).
    A trailing ';' returns to command mode with OK (voice dialling). Outcome:
      --silent                 nothing at all, ever (a modem switched off: no echo,
                               no results; command lines are still logged)
      --no-dialtone            NO DIALTONE after 0.3 s, for every dial
      --busy N                 BUSY after --ring-seconds
      --no-carrier N           NO CARRIER after --ring-seconds
      --no-answer N            NO ANSWER after --no-answer-seconds
      --connect N=PTYPATH      CONNECT 1200 after --ring-seconds, then data mode
      any other number         NO CARRIER after --ring-seconds
    Any character from the DTE while dialling aborts the dial: NO CARRIER.
  * Results, V1: CR LF text CR LF ("\\r\\nOK\\r\\n"); V0: the code and CR ("0\\r").
    Codes: 0 OK, 1 CONNECT, 2 RING, 3 NO CARRIER, 4 ERROR, 5 CONNECT 1200,
    6 NO DIALTONE, 7 BUSY, 8 NO ANSWER. X0 and X1 report BUSY, NO DIALTONE and
    NO ANSWER as NO CARRIER (X0 also CONNECT 1200 as CONNECT), X2 BUSY as NO CARRIER,
    X3 NO DIALTONE as NO CARRIER. Q1: no results at all.

Data mode (after CONNECT): PTYPATH (the concentrator's end of another socat pair,
opened raw when the call connects, its stale input flushed) and the DTE are bridged
both ways. The escape sequence is three S2 characters ('+'), the first after at least
the guard time (S12 in 1/50 s, from --guard, default 1 s) without characters from the
DTE, each within the guard time of the one before, and then the guard time with no
character: the modem then enters online command mode and answers OK. The '+'s are
passed to the line like any other data (a modem cannot know in advance). In online
command mode data from the line is discarded; ATO goes back to data mode (CONNECT
1200), ATH (or ATZ) ends the call with OK. --drop-after S drops the carrier S seconds
after CONNECT: the modem sends NO CARRIER, stops bridging and is in command mode.
When PTYPATH reports end of file or an error the carrier is lost the same way.

Output: one JSON object per line on stdout (flushed), each with "event" and "time"
(Unix seconds):
  {"event":"ready","dte":P,"guard":G,...}          once, when the DTE is open
  {"event":"command","raw":LINE,"command":"AT..."} each command line (also --silent)
  {"event":"ignored_line","raw":LINE}               a line without AT
  {"event":"result","text":"OK"|"CONNECT 1200"|...,"sent":"\\r\\nOK\\r\\n"}
  {"event":"dial","dial_string":D,"number":N,"outcome":O}
  {"event":"dial_aborted","by":HEX}
  {"event":"connect","number":N,"line":PTYPATH}
  {"event":"data","from":"dte"|"line","count":K,"hex":H}   (hex of the first 64)
  {"event":"line_data_dropped","count":K}           line data in online command mode
  {"event":"escape"}                                 +++ with its guard times
  {"event":"online","how":"ATO"}
  {"event":"hangup","how":"ATH"|"ATZ"}
  {"event":"carrier_lost","reason":R}
  {"event":"dte_closed"} / {"event":"exit","reason":R}
Exit codes: 0 (end of --run-for, DTE closed, SIGTERM), 3 setup error (message on
stderr).
"""

import argparse
import json
import os
import select
import signal
import sys
import termios
import time
import tty

CODES = {
    "OK": 0,
    "CONNECT": 1,
    "RING": 2,
    "NO CARRIER": 3,
    "ERROR": 4,
    "CONNECT 1200": 5,
    "NO DIALTONE": 6,
    "BUSY": 7,
    "NO ANSWER": 8,
}

DEFAULT_S = {0: 0, 1: 0, 2: 43, 3: 13, 4: 10, 5: 8, 6: 2, 7: 50, 8: 2, 9: 6,
             10: 14, 11: 95, 12: 50}

NO_DIALTONE_SECONDS = 0.3


def log(event, **kw):
    obj = {"event": event, "time": round(time.time(), 6)}
    obj.update(kw)
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def hexs(b):
    return " ".join("%02X" % x for x in b)


def open_raw(path):
    """Opens a terminal raw: 8 bits, no parity, no echo, no translation, no marks."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        tty.setraw(fd)
        iflag, oflag, cflag, lflag, ispeed, ospeed, cc = termios.tcgetattr(fd)
        iflag &= ~(termios.IGNBRK | termios.BRKINT | termios.PARMRK | termios.ISTRIP
                   | termios.INLCR | termios.IGNCR | termios.ICRNL | termios.IXON
                   | termios.IXOFF | termios.INPCK)
        oflag &= ~termios.OPOST
        lflag &= ~(termios.ECHO | termios.ECHONL | termios.ICANON | termios.ISIG
                   | termios.IEXTEN)
        cflag &= ~(termios.CSIZE | termios.PARENB)
        cflag |= termios.CS8 | termios.CREAD | termios.CLOCAL
        cc[termios.VMIN] = 1
        cc[termios.VTIME] = 0
        termios.tcsetattr(fd, termios.TCSANOW,
                          [iflag, oflag, cflag, lflag, ispeed, ospeed, cc])
    except termios.error:
        pass
    return fd


def write_all(fd, data):
    view = memoryview(bytes(data))
    deadline = time.monotonic() + 5.0
    while view:
        try:
            n = os.write(fd, view)
            view = view[n:]
        except BlockingIOError:
            if time.monotonic() > deadline:
                raise
            select.select([], [fd], [], 0.05)


def number_of(dial_string):
    return "".join(c for c in dial_string if c.isdigit() or c in "+*#")


class Modem:
    def __init__(self, args):
        self.args = args
        self.dte = open_raw(args.dte)
        self.connect = {}
        for spec in args.connect:
            if "=" not in spec:
                raise ValueError("--connect wants NUMBER=PTYPATH, got %r" % spec)
            num, path = spec.split("=", 1)
            self.connect[number_of(num)] = path
        self.busy = set(number_of(n) for n in args.busy)
        self.no_carrier = set(number_of(n) for n in args.no_carrier)
        self.no_answer = set(number_of(n) for n in args.no_answer)
        self.reset()
        self.mode = "command"  # command, dialing, data, online_command
        self.cmdbuf = bytearray()
        self.last_line = None
        self.line_fd = None
        self.call_number = None
        self.connect_time = None
        self.dial_due = None  # (time, outcome, number, path)
        # escape detection
        self.last_dte = 0.0
        self.plus_count = 0
        self.last_plus = 0.0
        self.escape_due = None

    def reset(self):
        self.echo = True
        self.verbose = True
        self.quiet = False
        self.xlevel = 4
        self.s = dict(DEFAULT_S)
        self.s[12] = max(0, min(255, int(round(self.args.guard * 50))))

    # ---- output -------------------------------------------------------------

    def to_dte(self, data):
        if self.args.silent or not data:
            return
        try:
            write_all(self.dte, data)
        except OSError as e:
            log("dte_write_failed", error=str(e))

    def result(self, name):
        shown = name
        x = self.xlevel
        if name in ("BUSY", "NO DIALTONE", "NO ANSWER") and x <= 1:
            shown = "NO CARRIER"
        elif name == "BUSY" and x == 2:
            shown = "NO CARRIER"
        elif name == "NO DIALTONE" and x == 3:
            shown = "NO CARRIER"
        if name == "CONNECT 1200" and x == 0:
            shown = "CONNECT"
        if self.quiet or self.args.silent:
            log("result", text=shown, sent=None)
            return
        if self.verbose:
            data = ("\r\n%s\r\n" % shown).encode()
        else:
            data = ("%d\r" % CODES[shown]).encode()
        log("result", text=shown, sent=data.decode())
        self.to_dte(data)

    def info(self, text):
        if self.quiet or self.args.silent:
            return
        if self.verbose:
            self.to_dte(("\r\n%s\r\n" % text).encode())
        else:
            self.to_dte(("%s\r\n" % text).encode())

    # ---- the call -----------------------------------------------------------

    def guard(self):
        return self.s[12] / 50.0

    def end_call(self):
        if self.line_fd is not None:
            try:
                os.close(self.line_fd)
            except OSError:
                pass
        self.line_fd = None
        self.call_number = None
        self.connect_time = None
        self.plus_count = 0
        self.escape_due = None

    def in_call(self):
        return self.mode in ("data", "online_command")

    def carrier_lost(self, reason):
        log("carrier_lost", reason=reason)
        self.end_call()
        self.mode = "command"
        self.result("NO CARRIER")

    def start_dial(self, dial_string):
        if self.args.silent:
            log("dial", dial_string=dial_string, number=number_of(dial_string),
                outcome="silent")
            return
        voice = dial_string.rstrip().endswith(";")
        num = number_of(dial_string)
        now = time.monotonic()
        ring = self.args.ring_seconds
        path = None
        if self.args.no_dialtone:
            outcome, due = "NO DIALTONE", now + NO_DIALTONE_SECONDS
        elif voice:
            outcome, due = "OK", now + ring
        elif num in self.busy:
            outcome, due = "BUSY", now + ring
        elif num in self.no_carrier:
            outcome, due = "NO CARRIER", now + ring
        elif num in self.no_answer:
            outcome, due = "NO ANSWER", now + self.args.no_answer_seconds
        elif num in self.connect:
            outcome, due, path = "CONNECT 1200", now + ring, self.connect[num]
        else:
            outcome, due = "NO CARRIER", now + ring
        log("dial", dial_string=dial_string, number=num, outcome=outcome,
            known=(num in self.connect or num in self.busy or num in self.no_carrier
                   or num in self.no_answer))
        self.mode = "dialing"
        self.dial_due = (due, outcome, num, path)

    def finish_dial(self):
        _, outcome, num, path = self.dial_due
        self.dial_due = None
        self.mode = "command"
        if outcome != "CONNECT 1200":
            self.result(outcome)
            return
        try:
            self.line_fd = open_raw(path)
            termios.tcflush(self.line_fd, termios.TCIFLUSH)
        except OSError as e:
            log("line_open_failed", line=path, error=str(e))
            self.line_fd = None
            self.result("NO CARRIER")
            return
        self.mode = "data"
        self.call_number = num
        self.connect_time = time.monotonic()
        self.last_dte = self.connect_time
        self.plus_count = 0
        self.escape_due = None
        log("connect", number=num, line=path)
        self.result("CONNECT 1200")

    # ---- command mode -------------------------------------------------------

    def command_bytes(self, data):
        for b in data:
            if self.mode == "dialing":
                log("dial_aborted", by="%02X" % b)
                self.dial_due = None
                self.mode = "command"
                self.result("NO CARRIER")
                self.cmdbuf = bytearray()
                continue
            if self.mode not in ("command", "online_command"):
                # A command switched to data mode: the rest belongs to it.
                return
            if self.echo:
                self.to_dte(bytes([b]))
            if b == self.s[3]:
                line = bytes(self.cmdbuf)
                self.cmdbuf = bytearray()
                self.command_line(line)
            elif b in (self.s[5], 0x7F):
                if self.cmdbuf:
                    self.cmdbuf.pop()
            elif b == self.s[4] and not self.cmdbuf:
                pass  # LF after CR
            else:
                self.cmdbuf.append(b)
                if len(self.cmdbuf) > 255:
                    self.cmdbuf = self.cmdbuf[-255:]
                if self.cmdbuf[-2:].upper() == b"A/":
                    self.cmdbuf = bytearray()
                    if self.last_line is not None:
                        self.command_line(self.last_line, repeated=True)

    def command_line(self, raw, repeated=False):
        text = raw.decode("latin-1")
        at = text.upper().find("AT")
        if at < 0:
            if text.strip():
                log("ignored_line", raw=text)
            return
        body = text[at + 2:]
        self.last_line = raw
        log("command", raw=text, command="AT" + body, repeated=repeated)
        if self.args.silent:
            return
        self.execute(body)

    def execute(self, body):
        i = 0
        n = len(body)

        def number(default=0):
            nonlocal i
            j = i
            while j < n and body[j].isdigit():
                j += 1
            if j == i:
                return default
            v = int(body[i:j])
            i = j
            return v

        final = "OK"
        while i < n:
            c = body[i].upper()
            i += 1
            if c == " ":
                continue
            if c == "D":
                if self.in_call():
                    self.result("ERROR")
                    return
                self.start_dial(body[i:])
                return
            if c == "E":
                v = number()
                if v > 1:
                    return self.result("ERROR")
                self.echo = v == 1
            elif c == "V":
                v = number()
                if v > 1:
                    return self.result("ERROR")
                self.verbose = v == 1
            elif c == "Q":
                v = number()
                if v > 1:
                    return self.result("ERROR")
                self.quiet = v == 1
            elif c == "X":
                v = number()
                if v > 4:
                    return self.result("ERROR")
                self.xlevel = v
            elif c == "Z":
                number()
                if self.in_call():
                    log("hangup", how="ATZ")
                    self.end_call()
                self.mode = "command"
                self.reset()
            elif c == "H":
                v = number()
                if v > 1:
                    return self.result("ERROR")
                if v == 0 and self.in_call():
                    log("hangup", how="ATH")
                    self.end_call()
                    self.mode = "command"
            elif c == "O":
                number()
                if self.mode != "online_command":
                    return self.result("NO CARRIER")
                self.mode = "data"
                self.last_dte = time.monotonic()
                self.plus_count = 0
                log("online", how="ATO")
                final = "CONNECT 1200"
                break
            elif c == "A":
                number()
                return self.result("NO CARRIER")
            elif c == "I":
                number()
                self.info("HARTKIT FAKE MODEM")
            elif c == "S":
                r = number(default=-1)
                if r < 0 or r > 255 or i >= n:
                    return self.result("ERROR")
                op = body[i]
                i += 1
                if op == "?":
                    self.info("%03d" % self.s.get(r, 0))
                elif op == "=":
                    v = number(default=0)
                    if v > 255:
                        return self.result("ERROR")
                    self.s[r] = v
                else:
                    return self.result("ERROR")
            elif c in "&%\\":
                if i >= n or not body[i].isalpha():
                    return self.result("ERROR")
                i += 1
                number()
            elif c in "BCFLMNPTWY":
                number()
            else:
                return self.result("ERROR")
        self.result(final)

    # ---- data mode ----------------------------------------------------------

    def data_bytes(self, data, now):
        guard = self.guard()
        plus = self.s[2]
        for b in data:
            if b == plus and plus <= 127:
                if self.plus_count == 0:
                    ok = now - self.last_dte >= guard
                else:
                    ok = self.plus_count < 3 and now - self.last_plus <= guard
                if ok:
                    self.plus_count += 1
                    self.last_plus = now
                else:
                    self.plus_count = 0
            else:
                self.plus_count = 0
            self.last_dte = now
        self.escape_due = (self.last_plus + guard) if self.plus_count == 3 else None
        log("data", **{"from": "dte", "count": len(data), "hex": hexs(data[:64])})
        if self.line_fd is not None:
            try:
                write_all(self.line_fd, data)
            except OSError as e:
                self.carrier_lost("line write failed: %s" % e)

    def line_bytes(self):
        try:
            data = os.read(self.line_fd, 4096)
        except BlockingIOError:
            return
        except OSError as e:
            self.carrier_lost("line read failed: %s" % e)
            return
        if not data:
            self.carrier_lost("line closed")
            return
        if self.mode == "data":
            log("data", **{"from": "line", "count": len(data), "hex": hexs(data[:64])})
            self.to_dte(data)
        else:
            log("line_data_dropped", count=len(data))

    # ---- main loop ----------------------------------------------------------

    def run(self):
        log("ready", dte=self.args.dte, guard=self.guard(),
            ring_seconds=self.args.ring_seconds, silent=self.args.silent,
            no_dialtone=self.args.no_dialtone, connect=self.connect,
            busy=sorted(self.busy), no_carrier=sorted(self.no_carrier),
            no_answer=sorted(self.no_answer), drop_after=self.args.drop_after)
        end = None
        if self.args.run_for is not None:
            end = time.monotonic() + self.args.run_for
        while True:
            now = time.monotonic()
            if end is not None and now >= end:
                log("exit", reason="run-for")
                return 0
            if self.dial_due is not None and now >= self.dial_due[0]:
                self.finish_dial()
                continue
            if self.escape_due is not None and self.mode == "data" and now >= self.escape_due:
                self.escape_due = None
                self.plus_count = 0
                self.mode = "online_command"
                self.cmdbuf = bytearray()
                log("escape")
                self.result("OK")
                continue
            if (self.args.drop_after is not None and self.in_call()
                    and now >= self.connect_time + self.args.drop_after):
                self.carrier_lost("--drop-after")
                continue
            timers = [t for t in (
                end,
                self.dial_due[0] if self.dial_due else None,
                self.escape_due if self.mode == "data" else None,
                (self.connect_time + self.args.drop_after)
                if self.args.drop_after is not None and self.in_call() else None,
            ) if t is not None]
            wait = max(0.0, min(timers) - now) if timers else 1.0
            fds = [self.dte]
            if self.line_fd is not None:
                fds.append(self.line_fd)
            ready, _, _ = select.select(fds, [], [], min(wait, 1.0))
            now = time.monotonic()
            if self.line_fd is not None and self.line_fd in ready:
                self.line_bytes()
            if self.dte in ready:
                try:
                    data = os.read(self.dte, 4096)
                except BlockingIOError:
                    continue
                except OSError as e:
                    log("dte_closed", error=str(e))
                    return 0
                if not data:
                    log("dte_closed")
                    return 0
                if self.mode == "data":
                    self.data_bytes(data, now)
                else:
                    self.command_bytes(data)


def main():
    p = argparse.ArgumentParser(
        description="A Hayes-compatible modem on a pseudo-terminal (see the docstring).")
    p.add_argument("dte", help="the modem's end of the DTE pseudo-terminal pair")
    p.add_argument("--connect", action="append", default=[], metavar="NUMBER=PTYPATH",
                   help="dialling NUMBER connects to PTYPATH (CONNECT 1200)")
    p.add_argument("--busy", action="append", default=[], metavar="NUMBER")
    p.add_argument("--no-carrier", action="append", default=[], metavar="NUMBER")
    p.add_argument("--no-answer", action="append", default=[], metavar="NUMBER")
    p.add_argument("--no-dialtone", action="store_true",
                   help="every dial answers NO DIALTONE")
    p.add_argument("--silent", action="store_true", help="answer nothing at all")
    p.add_argument("--ring-seconds", type=float, default=0.5)
    p.add_argument("--no-answer-seconds", type=float, default=2.0)
    p.add_argument("--guard", type=float, default=1.0,
                   help="escape guard time in seconds (S12 = guard * 50)")
    p.add_argument("--drop-after", type=float, default=None, metavar="SECONDS",
                   help="drop the carrier SECONDS after CONNECT")
    p.add_argument("--run-for", type=float, default=None, metavar="SECONDS")
    args = p.parse_args()
    signal.signal(signal.SIGTERM, lambda *_: (log("exit", reason="SIGTERM"), sys.exit(0)))
    try:
        modem = Modem(args)
    except (OSError, ValueError) as e:
        sys.stderr.write("fake_modem: %s\n" % e)
        return 3
    try:
        return modem.run()
    except KeyboardInterrupt:
        log("exit", reason="interrupt")
        return 0


if __name__ == "__main__":
    sys.exit(main())
