"""The C baseline of scale.py: a slave with no Python, as the machine's limit for 1 kHz sessions.

Not a benchmark itself: ``scale.py --slave c`` runs it (its docstring has the method). The program
below is written for this benchmark and compiled with the system's ``cc -O2`` at run time
(``_common.compile_c``, as datagram.py's C rows). It does what the raw uvloop baseline does, the
way a C program would:

- one non-blocking UDP socket on 127.0.0.1, a periodic ``timerfd`` (absolute first expiry, then
  every period) and the coordinator's pipe (stdin) in one ``epoll``;
- a peer's first datagram makes it a session (its address in an open-addressing table); every later
  one is counted, with its one-way lateness from the send-time stamp (one clock read per
  ``recvmmsg`` batch of up to 64, as tdtp stamps a batch);
- at each tick due, the ``tdtp.Ticker`` catch-up rule (a stall of more than ``max_catch_up``
  periods skips to the tick due now, the skipped ones counted late); per session, a clock read, the
  tick's lateness recorded (late: more than one period after its deadline, as the Python slaves
  measure it), a 100-byte sample with that time stamped in it; the tick's samples leave with
  ``sendmmsg`` (1024 a call), as tdtp's batched layer sends a wake-up's;
- ``spin`` as ``Ticker(spin=)``: the timer goes off that long before each deadline, the rest is
  waited on the CPU and counted.

The wrapper (:func:`c_slave_worker`) is a worker process like the Python slaves': the program,
its child, inherits its CPU pinning; it relays the port, the window and the report, and otherwise
sleeps on a pipe, so the slave's CPU is the program's (``getrusage`` of its own, over the window).
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path
from typing import Any

import _common as common
from _common import Json

C_SLAVE = r"""
/* scale.py's C baseline slave. usage: slave RATE LATE MAX_CATCH_UP PAYLOAD SPIN
 * Prints {"port": P}; then reads "START SECONDS" on stdin (the window, CLOCK_MONOTONIC seconds),
 * prints one JSON report once the window is over, and exits on "stop" or end of input. */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <endian.h>
#include <errno.h>
#include <math.h>
#include <netinet/in.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/timerfd.h>
#include <time.h>
#include <unistd.h>

#define MAXS 4096          /* sessions */
#define HASH 8192          /* table slots, a power of two above MAXS */
#define RB 64              /* recvmmsg batch */
#define SB 1024            /* sendmmsg batch (UIO_MAXIOV) */
#define PAY 256

static double now(void) { struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t); return t.tv_sec + t.tv_nsec / 1e9; }
/* This thread's CPU seconds: what a busy-wait costs (its wall time also counts a neighbour's turns). */
static double thread_cpu(void) { struct timespec ts; clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9; }
static double cpu(void) { struct rusage u; getrusage(RUSAGE_SELF, &u);
    return u.ru_utime.tv_sec + u.ru_utime.tv_usec / 1e6 + u.ru_stime.tv_sec + u.ru_stime.tv_usec / 1e6; }
static int cmp(const void *a, const void *b) { double x = *(const double *)a, y = *(const double *)b; return (x > y) - (x < y); }

static struct sockaddr_in peers[MAXS];
static int table[HASH];    /* session index + 1, 0 = free */
static int nsessions;
static double *lateness; static long nlate, caplate;
static double late_at[100]; static int nlate_at;
static long total, late, skipped, received, arrival_late;
static double wstart = INFINITY, wend = INFINITY, period, late_limit;

static int session_of(const struct sockaddr_in *a, int add) {
    uint64_t key = ((uint64_t)a->sin_addr.s_addr << 16) | a->sin_port;
    unsigned h = (unsigned)((key * 0x9E3779B97F4A7C15ull) >> 40) & (HASH - 1);
    for (;; h = (h + 1) & (HASH - 1)) {
        int i = table[h];
        if (i == 0) {
            if (!add || nsessions >= MAXS) return -1;
            peers[nsessions] = *a; table[h] = ++nsessions; return -2;  /* new: the hello */
        }
        if (peers[i - 1].sin_port == a->sin_port && peers[i - 1].sin_addr.s_addr == a->sin_addr.s_addr) return i - 1;
    }
}

static void record(double deadline, double t, long gap) {  /* scale.py's _record_tick */
    if (!(wstart <= deadline && deadline < wend)) return;
    total += 1 + gap; skipped += gap; late += gap;
    double l = t - deadline;
    if (nlate == caplate) { caplate = caplate ? 2 * caplate : 65536; lateness = realloc(lateness, caplate * sizeof(double)); }
    lateness[nlate++] = l;
    if (l > late_limit || gap) {
        late += l > late_limit;
        if (nlate_at < 100) late_at[nlate_at++] = round((deadline - wstart) * 1e4) / 1e4;
    }
}

static double pct(double q) {  /* nearest rank, as _common.percentile */
    if (!nlate) return NAN;
    long r = (long)ceil(q * nlate); if (r < 1) r = 1; if (r > nlate) r = nlate;
    return lateness[r - 1];
}

static void num(const char *key, double v) { if (isnan(v)) printf("\"%s\": NaN, ", key); else printf("\"%s\": %.9g, ", key, v); }

int main(int argc, char **argv) {
    if (argc != 6) return 2;
    double rate = atof(argv[1]); late_limit = atof(argv[2]);
    long catch_up = atol(argv[3]); int paylen = atoi(argv[4]); double spin = atof(argv[5]);
    if (paylen < 16 || paylen > PAY) return 2;
    period = 1.0 / rate;
    int fd = socket(AF_INET, SOCK_DGRAM | SOCK_NONBLOCK, 0);
    struct sockaddr_in a = {0}; a.sin_family = AF_INET; a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (bind(fd, (void *)&a, sizeof(a))) return 3;
    socklen_t al = sizeof(a); getsockname(fd, (void *)&a, &al);
    printf("{\"port\": %d}\n", ntohs(a.sin_port)); fflush(stdout);

    double anchor = now();
    long next_tick = spin > 0 ? 1 : 0;
    int tfd = timerfd_create(CLOCK_MONOTONIC, TFD_NONBLOCK | TFD_CLOEXEC);
    double first = anchor + next_tick * period - spin;
    struct itimerspec its = {{0, (long)llround(period * 1e9)}, {(time_t)first, (long)((first - (time_t)first) * 1e9)}};
    if (timerfd_settime(tfd, TFD_TIMER_ABSTIME, &its, NULL)) return 4;
    int ep = epoll_create1(0);
    struct epoll_event ev = {0};
    ev.events = EPOLLIN; ev.data.fd = fd; epoll_ctl(ep, EPOLL_CTL_ADD, fd, &ev);
    ev.data.fd = tfd; epoll_ctl(ep, EPOLL_CTL_ADD, tfd, &ev);
    ev.data.fd = 0; epoll_ctl(ep, EPOLL_CTL_ADD, 0, &ev);

    static char in[RB][2048], out[SB][PAY]; static struct sockaddr_in from[RB];
    static struct mmsghdr rm[RB], sm[SB]; static struct iovec ri[RB], si[SB];
    for (int i = 0; i < RB; i++) {
        ri[i].iov_base = in[i]; ri[i].iov_len = sizeof(in[i]);
        rm[i].msg_hdr.msg_iov = &ri[i]; rm[i].msg_hdr.msg_iovlen = 1;
    }
    for (int i = 0; i < SB; i++) {
        si[i].iov_base = out[i]; si[i].iov_len = paylen;
        sm[i].msg_hdr.msg_iov = &si[i]; sm[i].msg_hdr.msg_iovlen = 1;
        sm[i].msg_hdr.msg_namelen = sizeof(struct sockaddr_in);
    }
    double c0 = NAN, c1 = NAN, s0 = 0, s1 = 0, spun = 0; int ticking = 1, reported = 0;
    char line[256]; size_t linelen = 0;
    for (;;) {
        struct epoll_event evs[4];
        int n = epoll_wait(ep, evs, 4, 1);
        double t = now();
        if (isnan(c0) && t >= wstart) { c0 = cpu(); s0 = spun; }
        if (isnan(c1) && t >= wend) { c1 = cpu(); s1 = spun; }
        for (int k = 0; k < n; k++) {
            int which = evs[k].data.fd;
            if (which == fd) {
                for (;;) {
                    for (int i = 0; i < RB; i++) { rm[i].msg_hdr.msg_name = &from[i]; rm[i].msg_hdr.msg_namelen = sizeof(from[i]); }
                    int got = recvmmsg(fd, rm, RB, MSG_DONTWAIT, NULL);
                    if (got <= 0) break;
                    double at = now();
                    for (int i = 0; i < got; i++) {
                        if (session_of(&from[i], 1) < 0 || rm[i].msg_len < 8) continue;
                        if (!(wstart <= at && at < wend)) continue;
                        received++;
                        uint64_t be; memcpy(&be, in[i], 8); be = be64toh(be);
                        double stamp; memcpy(&stamp, &be, 8);
                        if (at - stamp > late_limit) arrival_late++;
                    }
                    if (got < RB) break;
                }
            } else if (which == tfd) {
                uint64_t expirations; if (read(tfd, &expirations, 8) < 0) continue;
                if (!ticking) continue;
                t = now();  /* the socket may have been served first in this wake-up */
                for (;;) {
                    /* Within spin of the next deadline (from this expiry, or because serving the
                     * last tick took until then): wait for it here, else the periodic timer's next
                     * expiry, spin before the deadline after it, would serve it period - spin late. */
                    double due_at = anchor + next_tick * period;
                    if (due_at - t > spin) break;
                    if (due_at > t) { double spent = thread_cpu(); while (t < due_at) t = now(); spun += thread_cpu() - spent; }
                    long tick = next_tick; double deadline = anchor + tick * period;
                    long gap = 0, behind = (long)((t - deadline) * rate);
                    if (behind > catch_up) { gap = behind; tick += behind; deadline = anchor + tick * period; }
                    next_tick = tick + 1;
                    int batch = 0;
                    for (int s = 0; s < nsessions; s++) {
                        double ts = now();
                        record(deadline, ts, gap);
                        uint64_t be; memcpy(&be, &ts, 8); be = htobe64(be); memcpy(out[batch], &be, 8);
                        uint64_t ix = htobe64((uint64_t)tick); memcpy(out[batch] + 8, &ix, 8);
                        sm[batch].msg_hdr.msg_name = &peers[s];
                        if (++batch == SB || s == nsessions - 1) {
                            for (int off = 0; off < batch;) {
                                int sent = sendmmsg(fd, sm + off, batch - off, 0);
                                if (sent <= 0) break;  /* a full buffer: the rest are dropped */
                                off += sent;
                            }
                            batch = 0;
                        }
                    }
                    t = now();
                }
                if (t > wend + 0.2) ticking = 0;
            } else {
                ssize_t r = read(0, line + linelen, sizeof(line) - 1 - linelen);
                if (r <= 0) return 0;
                linelen += r; line[linelen] = 0;
                if (strstr(line, "stop")) return 0;
                char *nl = strchr(line, '\n');
                if (nl && isinf(wstart)) {
                    double seconds; if (sscanf(line, "%lf %lf", &wstart, &seconds) == 2) wend = wstart + seconds;
                    linelen = 0;
                }
            }
        }
        if (!reported && !isnan(c1) && t >= wend + 0.05) {
            reported = 1;
            double span = wend - wstart;
            qsort(lateness, nlate, sizeof(double), cmp);
            printf("{\"sessions\": %d, \"ticks\": %ld, \"late\": %ld, \"skipped\": %ld, ", nsessions, total, late, skipped);
            num("late_fraction", total ? (double)late / total : NAN);
            num("tick_lateness_p99_us", 1e6 * pct(0.99));
            printf("\"tick_lateness_us\": {");
            num("p50", 1e6 * pct(0.5)); num("p90", 1e6 * pct(0.9)); num("p99", 1e6 * pct(0.99)); num("p99.9", 1e6 * pct(0.999));
            printf("\"max\": %.9g}, \"late_at\": [", nlate ? 1e6 * lateness[nlate - 1] : 0.0);
            for (int i = 0; i < nlate_at; i++) printf("%s%.4f", i ? ", " : "", late_at[i]);
            printf("], ");
            num("cpu_percent", 100.0 * (c1 - c0) / span);
            num("spin_percent", 100.0 * (s1 - s0) / span);
            printf("\"received\": %ld, ", received);
            num("received_rate", received / span);
            printf("\"arrival_late\": %ld, ", arrival_late);
            num("arrival_late_fraction", received ? (double)arrival_late / received : NAN);
            printf("\"build\": \"c\"}\n");
            fflush(stdout);
        }
    }
}
"""


def compile_slave(workdir: Path) -> Path | None:
    """The C slave compiled into ``workdir``, or None without a C compiler."""
    return common.compile_c(C_SLAVE, workdir, "scale_slave", libraries=("m",))


def c_slave_worker(
    conn: Any,
    *,
    binary: str,
    seconds: float,
    cpu_slot: int,
    rate: float,
    late: float,
    max_catch_up: int,
    payload: int,
    spin: float = 0.0,
) -> None:
    """Run the C slave as this worker's child (pinned with it) and relay its messages."""
    common.pin_to_cpu(cpu_slot)
    args = [binary, repr(rate), repr(late), str(max_catch_up), str(payload), repr(spin)]
    with subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True) as proc:
        assert proc.stdin is not None and proc.stdout is not None
        try:
            conn.send(json.loads(proc.stdout.readline()))  # {"port": P}
            message: Json = {}
            while "start" not in message:
                message = conn.recv()
            proc.stdin.write(f"{message['start']!r} {seconds!r}\n")
            proc.stdin.flush()
            line = proc.stdout.readline()
            if not line:
                raise RuntimeError(f"the C slave exited (code {proc.wait()}) without a report")
            conn.send({"window": json.loads(line)})
            while "stop" not in message:
                message = conn.recv()
            proc.stdin.write("stop\n")
            proc.stdin.flush()
            proc.wait(10)
        finally:
            if proc.poll() is None:
                proc.kill()  # our own child, by its handle
    conn.send({"final": True})
