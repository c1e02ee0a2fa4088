"""A command's output as a terminal of a given width shows it, as text: the command runs in a
pseudo-terminal (so progress bars redraw as they do for a user), and its bytes are replayed on
a small screen model (carriage returns, cursor moves, line erases, wrapping at the width).

    python benchmarks/terminal_capture.py --columns 80 --out docs/screenshots/terminal-80.txt \\
        -- hispo-pl fit --config configs/demo.yaml --config configs/methods/hispo.yaml

What is left on the screen is written (the bars as they ended, not every redraw); colours and
styles are dropped. Standard library only.
"""

from __future__ import annotations

import argparse
import fcntl
import os
import re
import struct
import subprocess
import sys
import termios

_CSI = re.compile(r"\x1b\[([0-9;?]*)([A-Za-z])")
_OTHER_ESCAPE = re.compile(r"\x1b[()][A-Za-z0-9]|\x1b[=>78]")


def render(text: str, columns: int) -> list[str]:
    """The lines a terminal ``columns`` wide shows after receiving ``text`` (its whole
    history, scrolled-off lines included)."""
    lines: list[list[str]] = [[]]
    row = col = 0

    def put(ch: str) -> None:
        nonlocal row, col
        if col >= columns:  # the last column was written: this character wraps
            row, col = row + 1, 0
        while len(lines) <= row:
            lines.append([])
        line = lines[row]
        line.extend(" " * (col + 1 - len(line)))
        line[col] = ch
        col += 1

    i = 0
    text = _OTHER_ESCAPE.sub("", text)
    while i < len(text):
        ch = text[i]
        match = _CSI.match(text, i) if ch == "\x1b" else None
        if match:
            params, command = match.groups()
            n = int(params) if params.isdigit() else 1
            if command == "A":
                row = max(0, row - n)
            elif command == "B":
                row += n
            elif command == "C":
                col = min(columns - 1, col + n)
            elif command == "D":
                col = max(0, col - n)
            elif command == "G":
                col = max(0, n - 1)
            elif command == "K":
                while len(lines) <= row:
                    lines.append([])
                mode = int(params) if params.isdigit() else 0
                if mode == 0:
                    del lines[row][col:]
                elif mode == 2:
                    lines[row] = []
            i = match.end()
            continue
        if ch == "\r":
            col = 0
        elif ch == "\n":
            row, col = row + 1, min(col, columns - 1)
            while len(lines) <= row:
                lines.append([])
        elif ch == "\b":
            col = max(0, col - 1)
        elif ch == "\t":
            for _ in range(8 - col % 8):
                put(" ")
        elif ch >= " ":
            put(ch)
        i += 1
    out = ["".join(line).rstrip() for line in lines]
    while out and not out[-1]:
        out.pop()
    return out


def run_in_terminal(argv: list[str], columns: int, rows: int = 40) -> str:
    """Run ``argv`` with a pseudo-terminal of ``columns`` x ``rows`` as its stdin, stdout and
    stderr; what it wrote, as a terminal received it (newlines as ``\\r\\n``)."""
    leader, follower = os.openpty()
    fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", rows, columns, 0, 0))
    env = {**os.environ, "COLUMNS": str(columns), "LINES": str(rows), "TERM": "xterm"}
    process = subprocess.Popen(
        argv, stdin=follower, stdout=follower, stderr=follower, env=env, close_fds=True
    )
    os.close(follower)
    chunks = []
    while True:
        try:
            chunk = os.read(leader, 65536)
        except OSError:  # the terminal closed: every process on it has ended
            break
        if not chunk:
            break
        chunks.append(chunk)
    os.close(leader)
    process.wait()
    return b"".join(chunks).decode("utf-8", "replace")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--columns", type=int, default=80)
    parser.add_argument("--out", required=True, help="text file to write")
    parser.add_argument("command", nargs=argparse.REMAINDER, help="-- then the command")
    args = parser.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("give the command after --")
    screen = render(run_in_terminal(command, args.columns), args.columns)
    header = f"$ {' '.join(command)}   # a terminal {args.columns} columns wide"
    with open(args.out, "w", encoding="utf-8") as out:
        out.write("\n".join([header, *screen]) + "\n")
    print(f"{args.out}: {len(screen)} lines", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
