/*
 * simtime.c: a C library's threads on the simulation clock (MAVSDK's libcmavsdk.so in a mission process).
 *
 * harness.simclock.native builds this file once per machine (cc -O2 -shared -fPIC) and loads it with ctypes.
 * hs_patch() rewrites the GOT entries of one loaded library (the one whose path contains a given string) so
 * that its calls to the clock, sleeps, condition variables, futexes, poll/epoll/select, blocking receives,
 * timerfds and pthread_create come here instead of to libc. Nothing else in the process is touched: the
 * Python interpreter keeps the real libc.
 *
 * The model is the Python runtime's (harness/simclock/runtime.py), for C threads:
 *  - time: CLOCK_MONOTONIC/BOOTTIME read the sim time, CLOCK_REALTIME (and gettimeofday, time) the run's
 *    epoch plus sim time; CPU clocks stay real.
 *  - every blocking call becomes a *wait*: the thread is idle, with an optional sim-time deadline and the
 *    descriptors it waits for. A wait ends only while the gate is open (phase 0), and whoever ends it marks
 *    the thread busy first, under `mu`, so the clock thread's decision "everything is idle" and every wake-up
 *    are serialised. Data that arrives between phases leaves the thread *pending*: it runs in the next phase.
 *  - threads the library creates are *tracked*: phase 0 cannot end while one of them is busy. Other threads
 *    (Python's, calling into the library) are waiting only while inside a wait; the Python runtime asks
 *    hs_thread_waiting() about them.
 *  - condition variables and futexes are emulated (a signal releases every waiter on that address: spurious
 *    wake-ups are allowed by both), timerfds are eventfds that fire when sim time passes their deadline.
 *  - sends count as MAVLink sent to the vehicle, which the runtime settles before phase 0 ends.
 * The clock thread drives it: hs_begin(t) opens the gate, hs_try_close() ends the phase when it can.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <elf.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <link.h>
#include <linux/futex.h>
#include <poll.h>
#include <pthread.h>
#include <semaphore.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/eventfd.h>
#include <sys/mman.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <sys/resource.h>
#include <spawn.h>
#include <stddef.h>
#include <sys/syscall.h>
#include <sys/time.h>
#include <sys/timerfd.h>
#include <time.h>
#include <unistd.h>

#define NO_DEADLINE INT64_MAX
#define MAX_FDS 64
#define MAX_TIMERS 64
#define MAX_CONDS 1024

typedef struct tstate {
    struct tstate *next;
    int index; /* creation order: names the thread in a trace */
    pthread_t self;
    int evfd;            /* written to wake this thread */
    int tracked;         /* created by the library: counts in the phase's idle decision */
    int asks;            /* not MAVSDK's (whose input comes with its vehicle's MAVLink): pending asks for a phase */
    int waiting;         /* inside a wait */
    int released;        /* its wait was ended (by a wake, a deadline or its I/O): it runs */
    int pending;         /* its I/O or a wake came while the gate was closed: released at the next phase */
    int timed_out;
    int interrupted;     /* released for a signal (a timer of the runtime's): the call returns EINTR */
    int64_t deadline;    /* sim ns, NO_DEADLINE */
    const void *addr;    /* the condition variable or futex it waits on */
    int nfds;
    struct pollfd fds[MAX_FDS];
    pid_t pid;           /* a child process of the mission (simchild.c), not a thread: 0 for threads */
    int child_fd;        /* its connection (-1 until it says hello, and while it execs) */
    int pidfd;           /* readable when it has exited */
    pid_t parent;        /* the child of the mission that started it (0: the mission itself) */
    pid_t tid;           /* the kernel's id of the thread (diagnostics: which system call it is in) */
    char call[24];       /* the call it waits in, or last waited in (diagnostics) */
} tstate;

typedef struct {
    int fd;
    int64_t deadline;
    int64_t interval;
    int64_t now_at;  /* the sim time of the last "fire now" */
    int now_count;   /* how many in a row at that sim time */
} simtimer;

/* asio asks for "fire now" when its next timer is less than a microsecond away (it truncates to whole
 * microseconds), then finds no timer due and asks again: on a clock that moves that ends within a microsecond,
 * on sim time (frozen within a phase) it never would. After this many in one phase, the timer fires at the
 * next phase instead: time passes, as it would. */
#define FIRE_NOW_PER_PHASE 16

typedef struct {
    const void *cond;
    clockid_t clock;
} condclock;

static pthread_mutex_t mu = PTHREAD_MUTEX_INITIALIZER;
static pthread_cond_t changed = PTHREAD_COND_INITIALIZER; /* the clock thread waits on it */
static uint64_t generation;
static int64_t now_ns;
static int64_t epoch_ns;
static int gate_open;
static int closed; /* the run is over: every wait ends */
static uint64_t sent;
static tstate *threads;
static simtimer timers[MAX_TIMERS];
static condclock condclocks[MAX_CONDS];
static pthread_key_t tkey;
static pthread_once_t tkey_once = PTHREAD_ONCE_INIT;
static int patched_count;
static int thread_count;
static FILE *trace; /* HARNESS_SIMTIME_TRACE: every release, for comparing two runs */
static int active;  /* hs_configure ran: the hooks put their callers on sim time */
static __thread int wall_thread; /* the harness's own threads (the clock thread): hooks pass through */
static int sem_waiters; /* threads inside a semaphore wait here: sem_post looks for them only then */
static int want_fd = -1; /* written when a wait outside MAVSDK's core became ready between phases */

/* Whether the calling thread's clock and waits are sim time (the process hooks pass through otherwise). */
static int on_sim(void) { return __atomic_load_n(&active, __ATOMIC_ACQUIRE) && !wall_thread; }

#define TRACE(...)                                                                                        \
    do {                                                                                                  \
        if (trace) {                                                                                      \
            fprintf(trace, "%lld ", (long long)now_ns);                                                   \
            fprintf(trace, __VA_ARGS__);                                                                  \
            fputc('\n', trace);                                                                           \
        }                                                                                                 \
    } while (0)

/* -- the real functions ------------------------------------------------------------------------------ */

static int real_clock_gettime(clockid_t c, struct timespec *ts) { return clock_gettime(c, ts); }

static int real_poll(struct pollfd *f, nfds_t n, int ms) { return (int)syscall(SYS_poll, f, n, ms); }

/* -- thread states (mu held) ------------------------------------------------------------------------- */

static int busy_locked(void);

static void poke_locked(void) {
    generation++;
    pthread_cond_broadcast(&changed);
}

static void wake_fd(int fd) {
    uint64_t one = 1;
    ssize_t r = write(fd, &one, sizeof one);
    (void)r;
}

/* Read an eventfd's count if it has one (never blocks: a timer's eventfd may be blocking). */
static void drain_fd(int fd) {
    struct pollfd p = {.fd = fd, .events = POLLIN};
    if (real_poll(&p, 1, 0) > 0) {
        uint64_t v;
        ssize_t r = read(fd, &v, sizeof v);
        (void)r;
    }
}

static void close_child_fds_locked(tstate *t);

/* Send a child "G ns" (run) or "T ns" (the time). */
static void tell_child(tstate *t, char what) {
    if (t->child_fd < 0)
        return;
    char line[48];
    int n = snprintf(line, sizeof line, "%c %lld\n", what, (long long)now_ns);
    ssize_t r = send(t->child_fd, line, (size_t)n, MSG_NOSIGNAL);
    (void)r;
}

/* Mark a waiting thread busy and let it run; gated: outside phase 0 it is left pending. */
static void release_locked(tstate *t, int timed_out) {
    if (!t->waiting || t->released)
        return;
    if (!gate_open && !closed) {
        if (!t->pending && t->asks && want_fd >= 0)
            wake_fd(want_fd); /* the mission asks the channel for a phase (WAKE): nothing else would bring one */
        t->pending = 1;
        return;
    }
    t->released = 1;
    t->pending = 0;
    t->timed_out = timed_out;
    TRACE("release %d%s addr=%d fds=%d", t->index, timed_out ? " timeout" : "", t->addr != NULL, t->nfds);
    if (t->pid) { /* a child process runs: busy until it says it waits again */
        t->waiting = t->released = 0;
        close_child_fds_locked(t);
        tell_child(t, 'G');
        return;
    }
    wake_fd(t->evfd);
    if (!t->tracked)
        poke_locked(); /* a script thread (a blocking call, destroy) runs again: the clock thread must see it */
}

static void forget_thread(void *p) {
    tstate *t = p;
    pthread_mutex_lock(&mu);
    for (tstate **pp = &threads; *pp; pp = &(*pp)->next) {
        if (*pp == t) {
            *pp = t->next;
            break;
        }
    }
    poke_locked();
    pthread_mutex_unlock(&mu);
    close(t->evfd);
    free(t);
}

static void make_key(void) { pthread_key_create(&tkey, forget_thread); }

static tstate *new_state(int tracked) {
    tstate *t = calloc(1, sizeof *t);
    if (!t)
        abort();
    t->child_fd = t->pidfd = -1;
    t->evfd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    t->tracked = tracked;
    t->deadline = NO_DEADLINE;
    pthread_mutex_lock(&mu);
    t->index = tracked ? ++thread_count : -(++thread_count);
    TRACE("thread %d", t->index);
    t->next = threads;
    threads = t;
    pthread_mutex_unlock(&mu);
    return t;
}

static tstate *me(void) {
    pthread_once(&tkey_once, make_key);
    tstate *t = pthread_getspecific(tkey);
    if (!t) {
        t = new_state(0);
        t->asks = 1;
        t->self = pthread_self();
        t->tid = (pid_t)syscall(SYS_gettid);
        pthread_setspecific(tkey, t);
    }
    return t;
}

/* -- the wait ---------------------------------------------------------------------------------------- */

#define sim_wait(...) sim_wait_in(__VA_ARGS__, __func__)

/* Block the calling thread (idle) until released: by a wake on `addr`, its descriptors becoming ready,
 * sim time reaching `deadline`, or the end of the run. `fds` are polled, never consumed. Returns 1 when
 * the wait timed out. `mu` must NOT be held; `locked` says whether the caller registered under mu already
 * (cond/futex waits register atomically with their own checks). */
static int sim_wait_in(tstate *t, const struct pollfd *fds, int nfds, int64_t deadline, const void *addr, int locked,
                       const char *call) {
    if (!locked)
        pthread_mutex_lock(&mu);
    snprintf(t->call, sizeof t->call, "%s", strncmp(call, "hs_", 3) == 0 ? call + 3 : call);
    if (closed) {
        /* The run is over and the process about to end: wait a little on the real clock (a spurious wake-up for
         * condition variables and futexes, which both allow one) so that no thread spins meanwhile. */
        pthread_mutex_unlock(&mu);
        struct pollfd pf[MAX_FDS];
        int n = nfds > MAX_FDS ? MAX_FDS : nfds;
        if (n)
            memcpy(pf, fds, (size_t)n * sizeof *pf);
        real_poll(pf, (nfds_t)n, 10);
        return deadline != NO_DEADLINE;
    }
    if (nfds > MAX_FDS)
        nfds = MAX_FDS;
    t->nfds = nfds;
    if (nfds)
        memcpy(t->fds, fds, (size_t)nfds * sizeof *fds);
    t->deadline = deadline;
    t->addr = addr;
    t->released = t->pending = t->timed_out = t->interrupted = 0;
    t->waiting = 1;
    if (closed || (deadline != NO_DEADLINE && deadline <= now_ns && gate_open))
        release_locked(t, !closed);
    /* The clock thread looks again only when this can end the library's turn or the phase: the library's last
     * busy thread waits, or a thread of the script's (a caller) does. Waking it at every wait of every thread
     * made it look ~30 times a phase. */
    if (!t->tracked || busy_locked() == 0)
        poke_locked();
    pthread_mutex_unlock(&mu);

    struct pollfd pfd[MAX_FDS + 1];
    for (;;) {
        pthread_mutex_lock(&mu);
        int released = t->released, pending = t->pending;
        pthread_mutex_unlock(&mu);
        if (released)
            break;
        int n = 0;
        if (!pending) { /* while pending, only a wake counts: the descriptors stay ready */
            for (int i = 0; i < t->nfds; i++)
                pfd[n++] = t->fds[i];
        }
        pfd[n].fd = t->evfd;
        pfd[n].events = POLLIN;
        pfd[n].revents = 0;
        int r = real_poll(pfd, (nfds_t)n + 1, -1);
        if (r < 0 && errno != EINTR)
            break; /* cannot wait at all: return rather than spin */
        if (pfd[n].revents)
            drain_fd(t->evfd);
        int ready = 0;
        for (int i = 0; i < n; i++)
            ready |= pfd[i].revents != 0;
        if (ready) {
            pthread_mutex_lock(&mu);
            release_locked(t, 0);
            if (t->pending)
                poke_locked();
            pthread_mutex_unlock(&mu);
        }
    }
    pthread_mutex_lock(&mu);
    int timed_out = t->timed_out;
    t->waiting = t->released = t->pending = 0;
    t->addr = NULL;
    t->nfds = 0;
    pthread_mutex_unlock(&mu);
    return timed_out;
}

/* -1 with EINTR when the thread's last wait was ended for a signal (hs_interrupt), else 0. */
static int interrupted(const tstate *t) {
    if (!t->interrupted)
        return 0;
    errno = EINTR;
    return -1;
}

static int64_t ts_ns(const struct timespec *ts) { return (int64_t)ts->tv_sec * 1000000000LL + ts->tv_nsec; }

static int64_t add_ns(int64_t a, int64_t b) { return (b > 0 && a > NO_DEADLINE - b) ? NO_DEADLINE : a + b; }

static int64_t sim_now(void) { return __atomic_load_n(&now_ns, __ATOMIC_ACQUIRE); }

static int is_sim_clock(clockid_t c) {
    return c == CLOCK_MONOTONIC || c == CLOCK_MONOTONIC_RAW || c == CLOCK_MONOTONIC_COARSE || c == CLOCK_BOOTTIME;
}

static int is_wall_clock(clockid_t c) { return c == CLOCK_REALTIME || c == CLOCK_REALTIME_COARSE || c == CLOCK_TAI; }

/* An absolute time on clock `c` as a sim deadline. */
static int64_t abs_deadline(clockid_t c, const struct timespec *abst) {
    if (!abst)
        return NO_DEADLINE;
    int64_t v = ts_ns(abst);
    return is_wall_clock(c) ? v - epoch_ns : v;
}

/* -- the wrappers ------------------------------------------------------------------------------------- */

static int hs_clock_gettime(clockid_t c, struct timespec *ts) {
    int64_t v;
    if (!on_sim())
        return real_clock_gettime(c, ts);
    if (is_sim_clock(c))
        v = sim_now();
    else if (is_wall_clock(c))
        v = epoch_ns + sim_now();
    else
        return real_clock_gettime(c, ts);
    ts->tv_sec = v / 1000000000LL;
    ts->tv_nsec = v % 1000000000LL;
    return 0;
}

static int hs_gettimeofday(struct timeval *tv, void *tz) {
    if (!on_sim())
        return gettimeofday(tv, tz);
    if (tv) {
        int64_t v = epoch_ns + sim_now();
        tv->tv_sec = v / 1000000000LL;
        tv->tv_usec = (v % 1000000000LL) / 1000;
    }
    return 0;
}

static time_t hs_time(time_t *out) {
    if (!on_sim())
        return time(out);
    time_t v = (time_t)((epoch_ns + sim_now()) / 1000000000LL);
    if (out)
        *out = v;
    return v;
}

static int hs_nanosleep(const struct timespec *req, struct timespec *rem) {
    if (!on_sim())
        return nanosleep(req, rem);
    if (rem)
        rem->tv_sec = rem->tv_nsec = 0;
    if (!req || ts_ns(req) <= 0)
        return 0;
    tstate *t = me();
    sim_wait(t, NULL, 0, add_ns(sim_now(), ts_ns(req)), NULL, 0);
    return interrupted(t);
}

static clockid_t cond_clock(const void *c) {
    clockid_t clk = CLOCK_REALTIME;
    pthread_mutex_lock(&mu);
    for (int i = 0; i < MAX_CONDS; i++) {
        if (condclocks[i].cond == c) {
            clk = condclocks[i].clock;
            break;
        }
    }
    pthread_mutex_unlock(&mu);
    return clk;
}

static int hs_cond_init(pthread_cond_t *c, const pthread_condattr_t *a) {
    int r = pthread_cond_init(c, a);
    clockid_t clk = CLOCK_REALTIME;
    if (a)
        pthread_condattr_getclock(a, &clk);
    pthread_mutex_lock(&mu);
    int slot = -1;
    for (int i = 0; i < MAX_CONDS; i++) {
        if (condclocks[i].cond == c) {
            slot = i;
            break;
        }
        if (slot < 0 && !condclocks[i].cond)
            slot = i;
    }
    if (slot >= 0 && clk != CLOCK_REALTIME) {
        condclocks[slot].cond = c;
        condclocks[slot].clock = clk;
    } else if (slot >= 0 && condclocks[slot].cond == c) {
        condclocks[slot].cond = NULL;
    }
    pthread_mutex_unlock(&mu);
    return r;
}

static int hs_cond_destroy(pthread_cond_t *c) {
    pthread_mutex_lock(&mu);
    for (int i = 0; i < MAX_CONDS; i++) {
        if (condclocks[i].cond == c)
            condclocks[i].cond = NULL;
    }
    pthread_mutex_unlock(&mu);
    return pthread_cond_destroy(c);
}

static int cond_wait(pthread_cond_t *c, pthread_mutex_t *m, int64_t deadline) {
    tstate *t = me();
    pthread_mutex_lock(&mu); /* registered while `m` is still held: a signal after this finds us */
    pthread_mutex_unlock(m);
    int timed_out = sim_wait(t, NULL, 0, deadline, c, 1);
    pthread_mutex_lock(m);
    return timed_out && deadline != NO_DEADLINE ? ETIMEDOUT : 0; /* an untimed wait never times out */
}

static int hs_cond_wait(pthread_cond_t *c, pthread_mutex_t *m) { return cond_wait(c, m, NO_DEADLINE); }

static int hs_cond_timedwait(pthread_cond_t *c, pthread_mutex_t *m, const struct timespec *abst) {
    return cond_wait(c, m, abs_deadline(cond_clock(c), abst));
}

static int wake_addr(const void *addr) {
    int n = 0;
    pthread_mutex_lock(&mu);
    for (tstate *t = threads; t; t = t->next) {
        if (t->waiting && !t->released && t->addr == addr) {
            release_locked(t, 0);
            n++;
        }
    }
    pthread_mutex_unlock(&mu); /* a release makes the phase busier: nothing for the clock thread to look at */
    return n;
}

static int hs_cond_signal(pthread_cond_t *c) {
    wake_addr(c);
    return pthread_cond_broadcast(c);
}

static int hs_cond_broadcast(pthread_cond_t *c) {
    wake_addr(c);
    return pthread_cond_broadcast(c);
}

static int64_t ms_deadline(int ms) { return ms < 0 ? NO_DEADLINE : add_ns(sim_now(), (int64_t)ms * 1000000LL); }

static int hs_poll(struct pollfd *fds, nfds_t n, int ms) {
    if (ms == 0 || !on_sim())
        return real_poll(fds, n, ms);
    int64_t deadline = ms_deadline(ms);
    tstate *t = me();
    for (;;) {
        int r = real_poll(fds, n, 0);
        if (r != 0)
            return r;
        if (sim_wait(t, fds, (int)n, deadline, NULL, 0))
            return real_poll(fds, n, 0);
    }
}

static int hs_epoll_wait(int ep, struct epoll_event *ev, int max, int ms) {
    if (ms == 0 || !on_sim())
        return epoll_wait(ep, ev, max, ms);
    int64_t deadline = ms_deadline(ms);
    tstate *t = me();
    struct pollfd p = {.fd = ep, .events = POLLIN};
    for (;;) {
        int r = epoll_wait(ep, ev, max, 0);
        if (r != 0)
            return r;
        if (sim_wait(t, &p, 1, deadline, NULL, 0))
            return epoll_wait(ep, ev, max, 0);
    }
}

static int hs_select(int nfds, fd_set *r, fd_set *w, fd_set *e, struct timeval *tv) {
    struct timeval zero = {0, 0};
    if ((tv && tv->tv_sec == 0 && tv->tv_usec == 0) || !on_sim())
        return select(nfds, r, w, e, tv);
    int64_t deadline = tv ? add_ns(sim_now(), (int64_t)tv->tv_sec * 1000000000LL + (int64_t)tv->tv_usec * 1000) : NO_DEADLINE;
    fd_set r0, w0, e0;
    if (r) r0 = *r;
    if (w) w0 = *w;
    if (e) e0 = *e;
    struct pollfd p[MAX_FDS];
    int n = 0;
    for (int fd = 0; fd < nfds && n < MAX_FDS; fd++) {
        short evs = (short)((r && FD_ISSET(fd, &r0) ? POLLIN : 0) | (w && FD_ISSET(fd, &w0) ? POLLOUT : 0) |
                            (e && FD_ISSET(fd, &e0) ? POLLPRI : 0));
        if (evs) {
            p[n].fd = fd;
            p[n].events = evs;
            p[n++].revents = 0;
        }
    }
    tstate *t = me();
    for (;;) {
        if (r) *r = r0;
        if (w) *w = w0;
        if (e) *e = e0;
        struct timeval z = zero;
        int res = select(nfds, r, w, e, &z);
        if (res != 0)
            return res;
        if (sim_wait(t, p, n, deadline, NULL, 0)) {
            if (r) *r = r0;
            if (w) *w = w0;
            if (e) *e = e0;
            z = zero;
            return select(nfds, r, w, e, &z);
        }
    }
}

static int nonblocking(int fd) { return (fcntl(fd, F_GETFL) & O_NONBLOCK) != 0; }

/* The socket's SO_RCVTIMEO as a sim deadline. */
static int64_t rcv_deadline(int fd) {
    struct timeval tv = {0, 0};
    socklen_t len = sizeof tv;
    if (getsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, &len) != 0 || (tv.tv_sec == 0 && tv.tv_usec == 0))
        return NO_DEADLINE;
    return add_ns(sim_now(), (int64_t)tv.tv_sec * 1000000000LL + (int64_t)tv.tv_usec * 1000);
}

/* Traced receives: the MAVLink frames of a datagram (message ids), to see in which phase each was read. */
static void trace_frames(const char *what, int fd, const unsigned char *b, ssize_t n) {
    if (!trace || n <= 0)
        return;
    char ids[256];
    size_t at = 0;
    ids[0] = 0;
    for (ssize_t i = 0; i + 10 <= n && at < sizeof ids - 16;) {
        if (b[i] != 0xFD) {
            i++;
            continue;
        }
        unsigned id = b[i + 7] | (unsigned)b[i + 8] << 8 | (unsigned)b[i + 9] << 16;
        at += (size_t)snprintf(ids + at, sizeof ids - at, " %u/%u", id, b[i + 4]);
        i += 12 + b[i + 1] + ((b[i + 2] & 1) ? 13 : 0);
    }
    pthread_mutex_lock(&mu);
    TRACE("%s fd=%d n=%zd%s", what, fd, n, ids);
    pthread_mutex_unlock(&mu);
}

/* A blocking receive: try without blocking, else wait (idle) for the socket on the sim clock. */
#define BLOCKING_RECV(fd, flags, call)                                                                    \
    do {                                                                                                  \
        if (((flags) & MSG_DONTWAIT) || nonblocking(fd))                                                 \
            return call((flags));                                                                         \
        int64_t deadline_ = rcv_deadline(fd);                                                             \
        struct pollfd p_ = {.fd = (fd), .events = POLLIN};                                                \
        tstate *t_ = me();                                                                                \
        for (;;) {                                                                                        \
            ssize_t r_ = call((flags) | MSG_DONTWAIT);                                                    \
            if (r_ >= 0 || (errno != EAGAIN && errno != EWOULDBLOCK))                                     \
                return r_;                                                                                \
            if (sim_wait(t_, &p_, 1, deadline_, NULL, 0)) {                                               \
                errno = EAGAIN;                                                                           \
                return -1;                                                                                \
            }                                                                                             \
        }                                                                                                 \
    } while (0)

static ssize_t recv_traced(int fd, void *buf, size_t len, int flags) {
    ssize_t r = recv(fd, buf, len, flags);
    trace_frames("recv", fd, buf, r);
    return r;
}

static ssize_t recvfrom_traced(int fd, void *buf, size_t len, int flags, struct sockaddr *a, socklen_t *al) {
    ssize_t r = recvfrom(fd, buf, len, flags, a, al);
    trace_frames("recv", fd, buf, r);
    return r;
}

static int recvmmsg_traced(int fd, struct mmsghdr *v, unsigned int n, int flags) {
    int r = recvmmsg(fd, v, n, flags, NULL);
    for (int i = 0; i < r; i++)
        trace_frames("recv", fd, v[i].msg_hdr.msg_iov[0].iov_base, (ssize_t)v[i].msg_len);
    return r;
}

static ssize_t hs_recv(int fd, void *buf, size_t len, int flags) {
#define CALL(f) recv_traced(fd, buf, len, f)
    BLOCKING_RECV(fd, flags, CALL);
#undef CALL
}

static ssize_t hs_recvfrom(int fd, void *buf, size_t len, int flags, struct sockaddr *a, socklen_t *al) {
#define CALL(f) recvfrom_traced(fd, buf, len, f, a, al)
    BLOCKING_RECV(fd, flags, CALL);
#undef CALL
}

static int hs_recvmmsg(int fd, struct mmsghdr *v, unsigned int n, int flags, struct timespec *tmo) {
    (void)tmo;
#define CALL(f) recvmmsg_traced(fd, v, n, f)
    BLOCKING_RECV(fd, flags, CALL);
#undef CALL
}

static int hs_accept(int fd, struct sockaddr *a, socklen_t *al) {
    if (nonblocking(fd))
        return accept(fd, a, al);
    struct pollfd p = {.fd = fd, .events = POLLIN};
    tstate *t = me();
    for (;;) {
        struct pollfd q = p;
        if (real_poll(&q, 1, 0) > 0)
            return accept(fd, a, al);
        sim_wait(t, &p, 1, NO_DEADLINE, NULL, 0);
    }
}

/* A datagram sent (counted for the runtime's settle); traced with its first ``len`` bytes at most. */
static void count_sent(int fd, ssize_t r, const void *b, size_t len) {
    if (r >= 0) {
        __atomic_add_fetch(&sent, 1, __ATOMIC_RELEASE);
        if (b)
            trace_frames("send", fd, b, (size_t)r < len ? r : (ssize_t)len);
    }
}

static ssize_t hs_sendto(int fd, const void *b, size_t n, int fl, const struct sockaddr *a, socklen_t al) {
    ssize_t r = sendto(fd, b, n, fl, a, al);
    count_sent(fd, r, b, n);
    return r;
}

static ssize_t hs_send(int fd, const void *b, size_t n, int fl) {
    ssize_t r = send(fd, b, n, fl);
    count_sent(fd, r, b, n);
    return r;
}

static ssize_t hs_sendmsg(int fd, const struct msghdr *m, int fl) {
    ssize_t r = sendmsg(fd, m, fl);
    count_sent(fd, r, m->msg_iovlen ? m->msg_iov[0].iov_base : NULL, m->msg_iovlen ? m->msg_iov[0].iov_len : 0);
    return r;
}

static int hs_sendmmsg(int fd, struct mmsghdr *v, unsigned int n, int fl) {
    int r = sendmmsg(fd, v, n, fl);
    for (int i = 0; i < r; i++)
        count_sent(fd, (ssize_t)v[i].msg_len, v[i].msg_hdr.msg_iov[0].iov_base, v[i].msg_hdr.msg_iov[0].iov_len);
    return r;
}

/* timerfds are eventfds (a read gives the expirations, as a timerfd's does) written when sim time passes. */
static int hs_timerfd_create(int clockid, int flags) {
    (void)clockid;
    int fd = eventfd(0, (flags & TFD_NONBLOCK ? EFD_NONBLOCK : 0) | (flags & TFD_CLOEXEC ? EFD_CLOEXEC : 0));
    if (fd < 0)
        return fd;
    pthread_mutex_lock(&mu);
    int ok = 0;
    for (int i = 0; i < MAX_TIMERS; i++) {
        if (timers[i].fd == 0) {
            timers[i].fd = fd + 1; /* 0 marks a free slot */
            timers[i].deadline = NO_DEADLINE;
            timers[i].interval = 0;
            ok = 1;
            break;
        }
    }
    pthread_mutex_unlock(&mu);
    if (!ok) {
        close(fd);
        errno = EMFILE;
        return -1;
    }
    return fd;
}

static void fire_due_timers_locked(void) {
    for (int i = 0; i < MAX_TIMERS; i++) {
        simtimer *tm = &timers[i];
        if (tm->fd && tm->deadline <= now_ns) {
            wake_fd(tm->fd - 1);
            if (tm->interval > 0) {
                while (tm->deadline <= now_ns)
                    tm->deadline = add_ns(tm->deadline, tm->interval);
            } else {
                tm->deadline = NO_DEADLINE;
            }
        }
    }
}

static int hs_timerfd_settime(int fd, int flags, const struct itimerspec *nv, struct itimerspec *old) {
    pthread_mutex_lock(&mu);
    simtimer *tm = NULL;
    for (int i = 0; i < MAX_TIMERS; i++) {
        if (timers[i].fd == fd + 1)
            tm = &timers[i];
    }
    if (!tm) {
        pthread_mutex_unlock(&mu);
        return timerfd_settime(fd, flags, nv, old);
    }
    if (old) {
        int64_t left = tm->deadline == NO_DEADLINE ? 0 : tm->deadline - now_ns;
        if (left < 0) left = 0;
        old->it_value.tv_sec = left / 1000000000LL;
        old->it_value.tv_nsec = left % 1000000000LL;
        old->it_interval.tv_sec = tm->interval / 1000000000LL;
        old->it_interval.tv_nsec = tm->interval % 1000000000LL;
    }
    int64_t v = ts_ns(&nv->it_value);
    tm->interval = ts_ns(&nv->it_interval);
    if (v == 0)
        tm->deadline = NO_DEADLINE;
    else if (flags & TFD_TIMER_ABSTIME)
        tm->deadline = v; /* on CLOCK_MONOTONIC, which reads sim time here */
    else
        tm->deadline = add_ns(now_ns, v);
    if (tm->deadline <= now_ns) {
        if (tm->now_at != now_ns) {
            tm->now_at = now_ns;
            tm->now_count = 0;
        }
        if (++tm->now_count > FIRE_NOW_PER_PHASE) {
            tm->deadline = now_ns + 1;
            TRACE("timer %d: fire-now again and again, at the next phase", fd);
        }
    }
    drain_fd(fd); /* re-arming discards expirations not yet read, as timerfd_settime does */
    if (tm->deadline <= now_ns && gate_open)
        fire_due_timers_locked();
    poke_locked();
    pthread_mutex_unlock(&mu);
    return 0;
}

static int hs_close_fd(int fd) {
    pthread_mutex_lock(&mu);
    for (int i = 0; i < MAX_TIMERS; i++) {
        if (timers[i].fd == fd + 1)
            timers[i].fd = 0;
    }
    pthread_mutex_unlock(&mu);
    return close(fd);
}

static long futex_wait(uint32_t *addr, uint32_t val, int64_t deadline) {
    tstate *t = me();
    pthread_mutex_lock(&mu);
    if (__atomic_load_n(addr, __ATOMIC_SEQ_CST) != val) {
        pthread_mutex_unlock(&mu);
        errno = EAGAIN;
        return -1;
    }
    if (sim_wait(t, NULL, 0, deadline, addr, 1) && deadline != NO_DEADLINE) {
        errno = ETIMEDOUT;
        return -1;
    }
    return 0;
}

static long hs_syscall(long nr, long a1, long a2, long a3, long a4, long a5, long a6) {
    if (nr == SYS_clock_gettime)
        return hs_clock_gettime((clockid_t)a1, (struct timespec *)a2);
    if (nr == SYS_gettimeofday)
        return hs_gettimeofday((struct timeval *)a1, (void *)a2);
    if (nr == SYS_futex) {
        int op = (int)a2 & FUTEX_CMD_MASK;
        uint32_t *addr = (uint32_t *)a1;
        const struct timespec *tmo = (const struct timespec *)a4;
        if (op == FUTEX_WAIT || op == FUTEX_WAIT_BITSET) {
            int64_t deadline = NO_DEADLINE;
            if (tmo) {
                if (op == FUTEX_WAIT)
                    deadline = add_ns(sim_now(), ts_ns(tmo));
                else
                    deadline = abs_deadline(((int)a2 & FUTEX_CLOCK_REALTIME) ? CLOCK_REALTIME : CLOCK_MONOTONIC, tmo);
            }
            return futex_wait(addr, (uint32_t)a3, deadline);
        }
        if (op == FUTEX_WAKE || op == FUTEX_WAKE_BITSET) {
            int n = wake_addr(addr);
            long r = syscall(nr, a1, a2, a3, a4, a5, a6);
            return r > n ? r : n;
        }
    }
    return syscall(nr, a1, a2, a3, a4, a5, a6);
}

typedef struct {
    void *(*fn)(void *);
    void *arg;
    tstate *t;
} start_args;

static void *trampoline(void *p) {
    start_args s = *(start_args *)p;
    free(p);
    pthread_once(&tkey_once, make_key);
    pthread_mutex_lock(&mu);
    s.t->self = pthread_self();
    s.t->tid = (pid_t)syscall(SYS_gettid);
    pthread_mutex_unlock(&mu);
    pthread_setspecific(tkey, s.t);
    return s.fn(s.arg);
}

static int hs_pthread_create(pthread_t *th, const pthread_attr_t *attr, void *(*fn)(void *), void *arg) {
    start_args *s = malloc(sizeof *s);
    if (!s)
        return EAGAIN;
    s->fn = fn;
    s->arg = arg;
    s->t = new_state(1); /* busy and counted from now on: what it does first happens in this phase */
    int r = pthread_create(th, attr, trampoline, s);
    if (r != 0) {
        forget_thread(s->t);
        free(s);
    }
    return r;
}

/* -- the process: waits of the interpreter and of any C extension (hs_patch_process) ------------------ */

static int hs_clock_nanosleep(clockid_t c, int flags, const struct timespec *req, struct timespec *rem) {
    if (!on_sim() || !(is_sim_clock(c) || is_wall_clock(c)))
        return clock_nanosleep(c, flags, req, rem);
    if (rem && !(flags & TIMER_ABSTIME))
        rem->tv_sec = rem->tv_nsec = 0;
    int64_t deadline = (flags & TIMER_ABSTIME) ? abs_deadline(c, req) : add_ns(sim_now(), ts_ns(req));
    if (!(flags & TIMER_ABSTIME) && ts_ns(req) <= 0)
        return 0;
    tstate *t = me();
    sim_wait(t, NULL, 0, deadline, NULL, 0);
    return t->interrupted ? EINTR : 0;
}

static int hs_usleep(useconds_t us) {
    if (!on_sim())
        return usleep(us);
    tstate *t = me();
    if (us > 0)
        sim_wait(t, NULL, 0, add_ns(sim_now(), (int64_t)us * 1000), NULL, 0);
    return interrupted(t);
}

static unsigned int hs_sleep(unsigned int s) {
    if (!on_sim())
        return sleep(s);
    if (s > 0)
        sim_wait(me(), NULL, 0, add_ns(sim_now(), (int64_t)s * 1000000000LL), NULL, 0);
    return 0;
}

/* A timed semaphore wait (CPython's Lock.acquire(timeout=...), SimpleQueue.get(timeout=...)): the deadline was
 * computed on the real clock (the interpreter reads it unpatched), so what is left of it starts now in sim time.
 * The thread waits on the semaphore's address; hs_sem_post releases it. */
static int sem_wait_sim(sem_t *s, int64_t remaining) {
    tstate *t = me();
    int64_t deadline = add_ns(sim_now(), remaining > 0 ? remaining : 0);
    __atomic_add_fetch(&sem_waiters, 1, __ATOMIC_SEQ_CST);
    int r;
    for (;;) {
        pthread_mutex_lock(&mu); /* registered under mu with the try: a post after the try finds us */
        if (sem_trywait(s) == 0) {
            pthread_mutex_unlock(&mu);
            r = 0;
            break;
        }
        int timed_out = sim_wait(t, NULL, 0, deadline, s, 1);
        if (t->interrupted) {
            r = interrupted(t);
            break;
        }
        if (timed_out) {
            r = sem_trywait(s) == 0 ? 0 : -1;
            if (r)
                errno = ETIMEDOUT;
            break;
        }
    }
    __atomic_sub_fetch(&sem_waiters, 1, __ATOMIC_SEQ_CST);
    return r;
}

static int64_t remaining_ns(clockid_t c, const struct timespec *abst) {
    struct timespec now;
    real_clock_gettime(c, &now);
    return ts_ns(abst) - ts_ns(&now);
}

static int hs_sem_clockwait(sem_t *s, clockid_t c, const struct timespec *abst) {
    if (!on_sim())
        return sem_clockwait(s, c, abst);
    return sem_wait_sim(s, remaining_ns(c, abst));
}

static int hs_sem_timedwait(sem_t *s, const struct timespec *abst) {
    if (!on_sim())
        return sem_timedwait(s, abst);
    return sem_wait_sim(s, remaining_ns(CLOCK_REALTIME, abst));
}

static int hs_sem_post(sem_t *s) {
    int r = sem_post(s);
    if (__atomic_load_n(&sem_waiters, __ATOMIC_SEQ_CST) > 0)
        wake_addr(s);
    return r;
}

static void *process_hook_for(const char *name);
static int patch_process_locked(void);
static pthread_mutex_t patch_mu = PTHREAD_MUTEX_INITIALIZER;

/* A library loaded later (an extension module, ctypes.CDLL) is put on sim time too. */
static void *hs_dlopen(const char *file, int mode) {
    void *h = dlopen(file, mode);
    if (h && __atomic_load_n(&active, __ATOMIC_ACQUIRE)) {
        pthread_mutex_lock(&patch_mu);
        patch_process_locked();
        pthread_mutex_unlock(&patch_mu);
    }
    return h;
}

/* ctypes looks functions up by name: a C function called through it (libc's usleep) is the hook. */
static void *hs_dlsym(void *h, const char *name) {
    void *r = dlsym(h, name);
    if (r && name && __atomic_load_n(&active, __ATOMIC_ACQUIRE)) {
        void *hk = process_hook_for(name);
        if (hk)
            return hk;
    }
    return r;
}

/* The calling thread is the harness's own (the clock thread), or becomes so (the main thread once the script has
 * ended): its clock and waits stay real whatever code it calls. */
void hs_set_wall(int wall) { wall_thread = wall; }

/* A thread a C extension starts (libzmq's I/O threads) counts in the idle decision like MAVSDK's, from its start. */
static int hs_foreign_pthread_create(pthread_t *th, const pthread_attr_t *attr, void *(*fn)(void *), void *arg) {
    if (!on_sim())
        return pthread_create(th, attr, fn, arg);
    start_args *s = malloc(sizeof *s);
    if (!s)
        return EAGAIN;
    s->fn = fn;
    s->arg = arg;
    s->t = new_state(1);
    s->t->asks = 1;
    int r = pthread_create(th, attr, trampoline, s);
    if (r != 0) {
        forget_thread(s->t);
        free(s);
    }
    return r;
}

/* End the wait of thread `self` for a signal (the runtime's signal timer): its call returns EINTR. 1 if it waited. */
int hs_interrupt(uint64_t self) {
    pthread_mutex_lock(&mu);
    int r = 0;
    for (tstate *th = threads; th; th = th->next) {
        if ((uint64_t)th->self == self && th->waiting && !th->released) {
            th->interrupted = 1;
            release_locked(th, 0);
            r = 1;
        }
    }
    pthread_mutex_unlock(&mu);
    return r;
}

/* The descriptor written when a wait outside MAVSDK's core became ready between phases (the runtime sends WAKE). */
int hs_want_fd(void) {
    pthread_mutex_lock(&mu);
    if (want_fd < 0)
        want_fd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
    pthread_mutex_unlock(&mu);
    return want_fd;
}

/* -- children: processes of the mission in its lockstep (simchild.c) ----------------------------------- */

#define MAX_CHILDREN 256
static int server_fd = -1;        /* listening: children connect here (an abstract unix socket) */
static int children_started;      /* the server thread runs */
static char static_warned[4096];  /* programs already reported as statically linked */

/* A child process, busy from now on (mu held): counted in the idle decision until it exits. */
static tstate *add_child_locked(pid_t pid) {
    for (tstate *t = threads; t; t = t->next) {
        if (t->pid == pid)
            return t;
    }
    tstate *t = calloc(1, sizeof *t);
    if (!t)
        abort();
    t->evfd = -1;
    t->child_fd = -1;
    t->tracked = 1;
    t->asks = 1;
    t->deadline = NO_DEADLINE;
    t->pid = pid;
    t->pidfd = (int)syscall(SYS_pidfd_open, pid, 0);
    t->index = ++thread_count;
    TRACE("child %d pid=%d", t->index, (int)pid);
    t->next = threads;
    threads = t;
    return t;
}

/* Close the mission's copies of a child's descriptors. */
static void close_child_fds_locked(tstate *t) {
    for (int i = 0; i < t->nfds; i++)
        close(t->fds[i].fd);
    t->nfds = 0;
}

/* A child waits for its descriptors " fd:events …": copies of them (pidfd_getfd) go into its wait, so that the clock
 * thread releases it when one is ready before it ends a phase (release_ready_locked), as for a thread of its own.
 * Without pidfd_getfd (an old kernel, a sandbox) the child's own "R" is all there is. */
static void take_child_fds_locked(tstate *t, const char *rest) {
    close_child_fds_locked(t);
    while (t->pidfd >= 0 && rest && *rest == ' ' && t->nfds < MAX_FDS) {
        int fd = atoi(rest + 1);
        const char *colon = strchr(rest + 1, ':');
        if (!colon)
            break;
        short events = (short)atoi(colon + 1);
        rest = strchr(colon, ' ');
        if (!(events & (POLLIN | POLLPRI)))
            continue; /* a copy of a write end would keep its reader from seeing the end of the stream */
        int copy = (int)syscall(SYS_pidfd_getfd, t->pidfd, fd, 0);
        if (copy >= 0) {
            fcntl(copy, F_SETFD, FD_CLOEXEC);
            t->fds[t->nfds].fd = copy;
            t->fds[t->nfds].events = events;
            t->fds[t->nfds++].revents = 0;
        }
    }
}

static void drop_child_locked(tstate *t) {
    for (tstate **pp = &threads; *pp; pp = &(*pp)->next) {
        if (*pp == t) {
            *pp = t->next;
            break;
        }
    }
    TRACE("child %d exited", t->index);
    close_child_fds_locked(t);
    /* Its parent, if a child of the mission too, runs now (SIGCHLD is on its way to it: when the parent takes the
     * "G", the signal has been handled and whatever its handler wrote is ready): in this phase, at any pace. */
    for (tstate *p = threads; t->parent && p; p = p->next) {
        if (p->pid == t->parent && p->waiting && !p->released)
            release_locked(p, 0);
    }
    if (t->child_fd >= 0)
        close(t->child_fd);
    if (t->pidfd >= 0)
        close(t->pidfd);
    free(t);
    poke_locked();
}

/* One message of a child (mu held): "H pid" hello, "F pid" it forked, "W ns" it waits (-1: no deadline), "R" a
 * descriptor it waits for is ready. */
static void child_says_locked(tstate *t, int fd, const char *line) {
    long long v = atoll(line + 2);
    switch (line[0]) {
    case 'H': {
        tstate *c = add_child_locked((pid_t)v);
        if (c->child_fd >= 0 && c->child_fd != fd)
            close(c->child_fd);
        c->child_fd = fd;
        c->waiting = c->released = c->pending = 0;
        tell_child(c, 'T');
        break;
    }
    case 'F':
        add_child_locked((pid_t)v)->parent = t ? t->pid : 0;
        break;
    case 'W':
        if (!t)
            break;
        t->waiting = 1;
        t->released = t->pending = t->timed_out = 0;
        t->deadline = v < 0 ? NO_DEADLINE : v;
        const char *call = strchr(line + 2, ' ');
        if (call) {
            size_t k = strcspn(call + 1, " \n");
            snprintf(t->call, sizeof t->call, "%.*s", (int)(k < sizeof t->call ? k : sizeof t->call - 1), call + 1);
            take_child_fds_locked(t, call + 1 + k);
        }
        if (gate_open && t->deadline <= now_ns)
            release_locked(t, 1);
        poke_locked();
        break;
    case 'R':
        if (t && t->waiting && !t->released)
            release_locked(t, 0);
        if (t && t->pending)
            poke_locked();
        break;
    }
}

/* Whether the program of process `pid` is statically linked (no PT_INTERP): nothing can be interposed in it. */
static int is_static(pid_t pid, char *exe, size_t cap) {
    char path[64];
    snprintf(path, sizeof path, "/proc/%d/exe", (int)pid);
    ssize_t n = readlink(path, exe, cap - 1);
    if (n <= 0)
        return 0;
    exe[n] = 0;
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0)
        return 0;
    ElfW(Ehdr) eh;
    int stat = 0;
    if (pread(fd, &eh, sizeof eh, 0) == (ssize_t)sizeof eh && memcmp(eh.e_ident, ELFMAG, SELFMAG) == 0) {
        stat = 1;
        for (int i = 0; i < eh.e_phnum; i++) {
            ElfW(Phdr) ph;
            if (pread(fd, &ph, sizeof ph, (off_t)(eh.e_phoff + (ElfW(Off))i * eh.e_phentsize)) != (ssize_t)sizeof ph)
                break;
            if (ph.p_type == PT_INTERP) {
                stat = 0;
                break;
            }
        }
    }
    close(fd);
    return stat;
}

/* The children's server (a thread of its own, on the wall clock): new connections, their messages, their exits. */
static void *serve_children(void *arg) {
    (void)arg;
    wall_thread = 1;
    char buf[4096];
    for (;;) {
        struct pollfd p[2 * MAX_CHILDREN + 1];
        tstate *who[2 * MAX_CHILDREN + 1];
        int n = 0;
        p[n].fd = server_fd;
        p[n].events = POLLIN;
        who[n++] = NULL;
        pthread_mutex_lock(&mu);
        for (tstate *t = threads; t && n < 2 * MAX_CHILDREN - 1; t = t->next) {
            if (!t->pid)
                continue;
            if (t->child_fd >= 0) {
                p[n].fd = t->child_fd;
                p[n].events = POLLIN;
                who[n++] = t;
            }
            if (t->pidfd >= 0) {
                p[n].fd = t->pidfd;
                p[n].events = POLLIN;
                who[n++] = t;
            }
        }
        pthread_mutex_unlock(&mu);
        int r = real_poll(p, (nfds_t)n, 200);
        pthread_mutex_lock(&mu);
        if (r == 0) { /* a quiet moment: a child that never said hello may be a program nothing can interpose */
            for (tstate *t = threads; t; t = t->next) {
                char exe[1024];
                if (t->pid && t->child_fd < 0 && !t->waiting && is_static(t->pid, exe, sizeof exe) &&
                    !strstr(static_warned, exe) && strlen(static_warned) + strlen(exe) + 2 < sizeof static_warned) {
                    strcat(static_warned, exe);
                    strcat(static_warned, "\n");
                    fprintf(stderr,
                            "harness mission: %s is statically linked: nothing can put it on the sim clock; it runs on "
                            "the wall clock, outside the phases\n",
                            exe);
                }
                if (t->pid && t->child_fd < 0 && !t->waiting && t->tracked && strstr(static_warned, exe) &&
                    is_static(t->pid, exe, sizeof exe)) {
                    t->tracked = 0; /* no longer waited for: a server (mavsdk_server) would hold phase 0 for good */
                    poke_locked();
                }
            }
        }
        for (int i = 0; i < n && r > 0; i++) {
            if (!p[i].revents)
                continue;
            tstate *t = who[i];
            if (!t) {
                int fd = accept4(server_fd, NULL, NULL, SOCK_CLOEXEC);
                if (fd >= 0) { /* its hello comes next, read at once: it waits for the answer */
                    ssize_t k = recv(fd, buf, sizeof buf - 1, 0);
                    if (k > 0) {
                        buf[k] = 0;
                        child_says_locked(NULL, fd, buf);
                    } else {
                        close(fd);
                    }
                }
                continue;
            }
            if (p[i].fd == t->pidfd) { /* exited */
                drop_child_locked(t);
                break; /* the list changed: look again */
            }
            if (p[i].fd != t->child_fd)
                continue; /* a connection it replaced (closed when the new one said hello) */
            ssize_t k = recv(t->child_fd, buf, sizeof buf - 1, MSG_DONTWAIT);
            if (k < 0 && (errno == EAGAIN || errno == EWOULDBLOCK))
                continue;
            if (k <= 0) { /* it exec'd or is exiting: busy until it says hello again or its pidfd says it ended */
                close(t->child_fd);
                t->child_fd = -1;
                t->waiting = t->released = t->pending = 0;
                close_child_fds_locked(t);
                continue;
            }
            buf[k] = 0;
            for (char *line = buf; line && *line; line = strchr(line, '\n') ? strchr(line, '\n') + 1 : NULL)
                child_says_locked(t, t->child_fd, line);
        }
        pthread_mutex_unlock(&mu);
    }
    return NULL;
}

/* Start the children's server at the abstract unix address `name`; 1 when it listens. Idempotent. */
int hs_children(const char *name) {
    if (children_started)
        return 1;
    int fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0)
        return 0;
    struct sockaddr_un a = {.sun_family = AF_UNIX};
    size_t len = strlen(name);
    if (len + 1 > sizeof a.sun_path)
        return 0;
    memcpy(a.sun_path + 1, name, len);
    if (bind(fd, (struct sockaddr *)&a, (socklen_t)(offsetof(struct sockaddr_un, sun_path) + 1 + len)) != 0 ||
        listen(fd, 64) != 0) {
        close(fd);
        return 0;
    }
    server_fd = fd;
    pthread_t th;
    if (pthread_create(&th, NULL, serve_children, NULL) != 0)
        return 0;
    pthread_detach(th);
    children_started = 1;
    return 1;
}

/* A process started by the mission counts from its first moment (fork, posix_spawn). */
static void started_child(pid_t pid) {
    if (pid <= 0 || !children_started || !on_sim())
        return;
    pthread_mutex_lock(&mu);
    add_child_locked(pid);
    pthread_mutex_unlock(&mu);
}

static pid_t hs_fork(void) {
    pid_t pid = fork();
    if (pid > 0)
        started_child(pid);
    return pid;
}

/* vfork's child borrows the caller's stack: a wrapper cannot return in it. A fork does the same for a child that
 * execs at once (subprocess). */
static pid_t hs_vfork(void) { return hs_fork(); }

static int hs_posix_spawn(pid_t *pid, const char *path, const posix_spawn_file_actions_t *fa,
                          const posix_spawnattr_t *at, char *const argv[], char *const envp[]) {
    int r = posix_spawn(pid, path, fa, at, argv, envp);
    if (r == 0 && pid)
        started_child(*pid);
    return r;
}

static int hs_posix_spawnp(pid_t *pid, const char *file, const posix_spawn_file_actions_t *fa,
                           const posix_spawnattr_t *at, char *const argv[], char *const envp[]) {
    int r = posix_spawnp(pid, file, fa, at, argv, envp);
    if (r == 0 && pid)
        started_child(*pid);
    return r;
}

/* A blocking wait for a child (subprocess's Popen.wait, asyncio's child watcher) is a sim-time wait on the child's
 * pidfd: the child runs meanwhile, and the waiter counts idle until the child has exited. */
static pid_t hs_wait4(pid_t pid, int *status, int options, struct rusage *ru) {
    if (on_sim() && !(options & WNOHANG)) {
        int pfd = pid > 0 ? (int)syscall(SYS_pidfd_open, pid, 0) : -1;
        tstate *t = me();
        for (;;) {
            pid_t r = wait4(pid, status, options | WNOHANG, ru);
            if (r != 0) {
                if (pfd >= 0)
                    close(pfd);
                return r;
            }
            if (pfd >= 0) {
                struct pollfd p = {.fd = pfd, .events = POLLIN};
                sim_wait(t, &p, 1, NO_DEADLINE, NULL, 0);
            } else {
                sim_wait(t, NULL, 0, add_ns(sim_now(), 20000000LL), NULL, 0); /* any child: look a phase later */
            }
        }
    }
    return wait4(pid, status, options, ru);
}

static pid_t hs_waitpid(pid_t pid, int *status, int options) { return hs_wait4(pid, status, options, NULL); }

/* -- the clock thread's side (called through ctypes) ------------------------------------------------- */

void hs_configure(int64_t epoch, int64_t t) {
    const char *path = getenv("HARNESS_SIMTIME_TRACE");
    if (path && *path && !trace) {
        trace = fopen(path, "w");
        if (trace)
            setvbuf(trace, NULL, _IOLBF, 0);
    }
    pthread_mutex_lock(&mu);
    epoch_ns = epoch;
    if (t > now_ns)
        __atomic_store_n(&now_ns, t, __ATOMIC_RELEASE);
    pthread_mutex_unlock(&mu);
    __atomic_store_n(&active, 1, __ATOMIC_RELEASE);
}

/* Phase 0 at sim time t begins: the gate opens and every pending wait runs. */
void hs_begin(int64_t t) {
    pthread_mutex_lock(&mu);
    if (t > now_ns)
        __atomic_store_n(&now_ns, t, __ATOMIC_RELEASE);
    gate_open = 1;
    for (tstate *th = threads; th; th = th->next) {
        if (th->pending)
            release_locked(th, 0);
    }
    pthread_mutex_unlock(&mu);
}

/* Release every waiting thread whose descriptors are ready (mu held). */
static int release_ready_locked(void) {
    int n = 0;
    for (tstate *th = threads; th; th = th->next) {
        if (!th->waiting || th->released || !th->nfds)
            continue;
        struct pollfd p[MAX_FDS];
        memcpy(p, th->fds, (size_t)th->nfds * sizeof *p);
        if (real_poll(p, (nfds_t)th->nfds, 0) != 0) {
            release_locked(th, 0);
            n++;
        }
    }
    return n;
}

static int busy_locked(void) {
    int n = 0;
    for (tstate *th = threads; th; th = th->next) {
        if (th->tracked && (!th->waiting || th->released))
            n++;
    }
    return n;
}

/* Release every waiting thread whose descriptors are ready now; how many. */
int hs_release_ready(void) {
    pthread_mutex_lock(&mu);
    int n = release_ready_locked();
    pthread_mutex_unlock(&mu);
    return n;
}

/* The absolute deadline, timeout_ns of wall time from now, for a timed wait on `changed`: on CLOCK_REALTIME, its
 * clock (a deadline on CLOCK_MONOTONIC had passed long ago, and the clock thread spun). */
static struct timespec changed_deadline(int64_t timeout_ns) {
    struct timespec ts;
    real_clock_gettime(CLOCK_REALTIME, &ts);
    int64_t until = ts_ns(&ts) + timeout_ns;
    ts.tv_sec = until / 1000000000LL;
    ts.tv_nsec = until % 1000000000LL;
    return ts;
}

/* Block (wall clock, at most timeout_ns) until every thread of the library waits with nothing ready (releasing
 * those whose descriptors are ready meanwhile): the clock thread lets the library take in a batch of input before
 * the script runs. 1 when it is so, 0 on timeout. Waiting here, without the GIL, instead of looking from Python
 * at every change, saves ~25 wake-ups of the clock thread a phase. */
int hs_wait_library_idle(int64_t timeout_ns) {
    struct timespec ts = changed_deadline(timeout_ns);
    pthread_mutex_lock(&mu);
    int r = 0;
    for (;;) {
        if (busy_locked() == 0 && release_ready_locked() == 0) {
            r = 1;
            break;
        }
        if (pthread_cond_timedwait(&changed, &mu, &ts) == ETIMEDOUT)
            break;
    }
    pthread_mutex_unlock(&mu);
    return r;
}

/* Busy tracked threads (0: every thread of the library waits). */
int hs_busy(void) {
    pthread_mutex_lock(&mu);
    int n = busy_locked();
    pthread_mutex_unlock(&mu);
    return n;
}

/* Try to end phase 0: 1 when every tracked thread waits with nothing ready and no deadline due (the gate is
 * then closed, atomically with that check); 0 when a thread is busy or was released now (I/O first, then
 * the deadlines that fell due), or when anything changed since generation `g`, which the caller read before it
 * found the script's threads idle: a script thread that a library thread released in between (MAVSDK's destroy
 * and its receiver hand over back and forth) is running, though the caller saw it waiting. */
int hs_try_close(uint64_t g) {
    pthread_mutex_lock(&mu);
    int r = 0;
    if (generation == g && busy_locked() == 0 && release_ready_locked() == 0) {
        int due = 0;
        fire_due_timers_locked();
        due = release_ready_locked(); /* a fired timerfd makes its epoll readable */
        if (!due) {
            for (tstate *th = threads; th; th = th->next) {
                if (th->waiting && !th->released && th->deadline <= now_ns) {
                    release_locked(th, 1);
                    due++;
                }
            }
        }
        if (!due) {
            gate_open = 0;
            r = 1;
            TRACE("close");
        }
    }
    pthread_mutex_unlock(&mu);
    return r;
}

/* Shut the gate for a moment within the phase (the runtime settles the script's MAVLink). */
void hs_pause(void) {
    pthread_mutex_lock(&mu);
    gate_open = 0;
    pthread_mutex_unlock(&mu);
}

/* Re-open a gate closed by hs_try_close or hs_pause (the Python side found work after all, or settled). */
void hs_reopen(void) { hs_begin(INT64_MIN); }

/* The earliest sim deadline of a waiting thread or an armed timer (NO_DEADLINE: none). */
int64_t hs_next_deadline(void) {
    pthread_mutex_lock(&mu);
    int64_t d = NO_DEADLINE;
    for (tstate *th = threads; th; th = th->next) {
        if (th->waiting && !th->released && th->deadline < d)
            d = th->deadline;
    }
    for (int i = 0; i < MAX_TIMERS; i++) {
        if (timers[i].fd && timers[i].deadline < d)
            d = timers[i].deadline;
    }
    pthread_mutex_unlock(&mu);
    return d;
}

/* Whether some waiting thread waits for descriptors (MAVLink arrives at every phase: no lookahead). */
int hs_waits_for_io(void) {
    pthread_mutex_lock(&mu);
    int r = 0;
    for (tstate *th = threads; th; th = th->next)
        r |= th->waiting && th->nfds > 0;
    pthread_mutex_unlock(&mu);
    return r;
}

/* 1 when thread `self` (a pthread_t, Python's thread ident) is inside a wait that has not ended. */
int hs_thread_waiting(uint64_t self) {
    pthread_mutex_lock(&mu);
    int r = 0;
    for (tstate *th = threads; th; th = th->next) {
        if ((uint64_t)th->self == self) {
            r = th->waiting && !th->released;
            break;
        }
    }
    pthread_mutex_unlock(&mu);
    return r;
}

uint64_t hs_sent(void) { return __atomic_load_n(&sent, __ATOMIC_ACQUIRE); }

uint64_t hs_generation(void) {
    pthread_mutex_lock(&mu);
    uint64_t g = generation;
    pthread_mutex_unlock(&mu);
    return g;
}

void hs_poke(void) {
    pthread_mutex_lock(&mu);
    poke_locked();
    pthread_mutex_unlock(&mu);
}

/* Block (wall clock, at most timeout_ns) until something changed since generation `g`. */
void hs_wait_change(uint64_t g, int64_t timeout_ns) {
    struct timespec ts = changed_deadline(timeout_ns);
    pthread_mutex_lock(&mu);
    while (generation == g) {
        if (pthread_cond_timedwait(&changed, &mu, &ts) == ETIMEDOUT)
            break;
    }
    pthread_mutex_unlock(&mu);
}

/* The run is over: every wait ends now and later ones return at once. */
void hs_close(void) {
    pthread_mutex_lock(&mu);
    closed = 1;
    gate_open = 1;
    for (tstate *th = threads; th; th = th->next) {
        if (th->waiting && !th->released)
            release_locked(th, 1);
    }
    pthread_mutex_unlock(&mu);
}

/* The system call thread `tid` of process `pid` is in now ("running" when none), for diagnostics. */
static void syscall_of(pid_t pid, pid_t tid, char *out, size_t cap) {
    static const struct {
        long nr;
        const char *name;
    } names[] = {{SYS_read, "read"}, {SYS_write, "write"}, {SYS_poll, "poll"}, {SYS_ppoll, "ppoll"},
                 {SYS_select, "select"}, {SYS_pselect6, "pselect6"}, {SYS_epoll_wait, "epoll_wait"},
                 {SYS_epoll_pwait, "epoll_pwait"}, {SYS_futex, "futex (a lock or condition variable)"},
                 {SYS_nanosleep, "nanosleep"}, {SYS_clock_nanosleep, "clock_nanosleep"}, {SYS_wait4, "wait4"},
                 {SYS_recvfrom, "recvfrom"}, {SYS_recvmsg, "recvmsg"}, {SYS_accept, "accept"}, {SYS_accept4, "accept4"},
                 {SYS_connect, "connect"}, {SYS_pause, "pause"}, {SYS_rt_sigsuspend, "sigsuspend"}};
    char path[64], buf[128];
    snprintf(path, sizeof path, "/proc/%d/task/%d/syscall", (int)pid, (int)tid);
    snprintf(out, cap, "?");
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0)
        return;
    ssize_t n = read(fd, buf, sizeof buf - 1);
    close(fd);
    if (n <= 0)
        return;
    buf[n] = 0;
    if (strncmp(buf, "running", 7) == 0) {
        snprintf(out, cap, "running");
        return;
    }
    long nr = atol(buf);
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++) {
        if (names[i].nr == nr) {
            snprintf(out, cap, "in %s", names[i].name);
            return;
        }
    }
    snprintf(out, cap, "in system call %ld", nr);
}

/* A description of every thread and child process that keeps phase 0 open (all of them with `all`), for the
 * runtime's warning before the watchdog drops the mission: which call each is in. */
int hs_describe(char *out, int cap) {
    pthread_mutex_lock(&mu);
    int n = 0;
    out[0] = 0;
    for (tstate *th = threads; th && n < cap - 200; th = th->next) {
        int busy = th->tracked && (!th->waiting || th->released);
        if (!busy)
            continue;
        char where[64], exe[256] = "";
        if (th->pid) {
            syscall_of(th->pid, th->pid, where, sizeof where);
            char path[64];
            snprintf(path, sizeof path, "/proc/%d/exe", (int)th->pid);
            ssize_t k = readlink(path, exe, sizeof exe - 1);
            exe[k > 0 ? k : 0] = 0;
            n += snprintf(out + n, (size_t)(cap - n), "child process %d (%s) busy, %s%s%s", (int)th->pid, exe, where,
                          th->child_fd < 0 ? ", not (yet) joined" : "", th->call[0] ? ", last waited in " : "");
        } else {
            syscall_of(getpid(), th->tid, where, sizeof where);
            n += snprintf(out + n, (size_t)(cap - n), "C thread %d (tid %d) busy, %s%s", th->index, (int)th->tid, where,
                          th->call[0] ? ", last waited in " : "");
        }
        if (th->call[0])
            n += snprintf(out + n, (size_t)(cap - n), "%s", th->call);
        n += snprintf(out + n, (size_t)(cap - n), "; ");
    }
    pthread_mutex_unlock(&mu);
    return n;
}

/* -- GOT patching ----------------------------------------------------------------------------------- */

typedef struct {
    const char *name;
    void *fn;
} hook;

static const hook hooks[] = {
    {"clock_gettime", (void *)hs_clock_gettime},
    {"gettimeofday", (void *)hs_gettimeofday},
    {"time", (void *)hs_time},
    {"nanosleep", (void *)hs_nanosleep},
    {"pthread_cond_init", (void *)hs_cond_init},
    {"pthread_cond_destroy", (void *)hs_cond_destroy},
    {"pthread_cond_wait", (void *)hs_cond_wait},
    {"pthread_cond_timedwait", (void *)hs_cond_timedwait},
    {"pthread_cond_signal", (void *)hs_cond_signal},
    {"pthread_cond_broadcast", (void *)hs_cond_broadcast},
    {"poll", (void *)hs_poll},
    {"epoll_wait", (void *)hs_epoll_wait},
    {"select", (void *)hs_select},
    {"recv", (void *)hs_recv},
    {"recvfrom", (void *)hs_recvfrom},
    {"recvmmsg", (void *)hs_recvmmsg},
    {"accept", (void *)hs_accept},
    {"send", (void *)hs_send},
    {"sendto", (void *)hs_sendto},
    {"sendmsg", (void *)hs_sendmsg},
    {"sendmmsg", (void *)hs_sendmmsg},
    {"timerfd_create", (void *)hs_timerfd_create},
    {"timerfd_settime", (void *)hs_timerfd_settime},
    {"close", (void *)hs_close_fd},
    {"syscall", (void *)hs_syscall},
    {"pthread_create", (void *)hs_pthread_create},
};

/* The interpreter (libpython and its own extension modules): only its timed lock waits, which no Python-level
 * patch reaches, and the loader. Its clock reads stay real: the Python-level patches (patch.py) own the
 * interpreter's time API, and the GIL's switch interval (a pthread_cond_timedwait on a deadline it reads from
 * the real clock) must stay on the wall clock: which thread holds the GIL never moves sim time. */
static const hook interp_hooks[] = {
    {"fork", (void *)hs_fork},
    {"vfork", (void *)hs_vfork},
    {"posix_spawn", (void *)hs_posix_spawn},
    {"posix_spawnp", (void *)hs_posix_spawnp},
    {"wait4", (void *)hs_wait4},
    {"waitpid", (void *)hs_waitpid},
    {"sem_clockwait", (void *)hs_sem_clockwait},
    {"sem_timedwait", (void *)hs_sem_timedwait},
    {"sem_post", (void *)hs_sem_post},
    {"dlopen", (void *)hs_dlopen},
    {"dlsym", (void *)hs_dlsym},
};

/* Every other library of the process (C extensions and what they load: libzmq, ...), and C functions looked up
 * by name (ctypes): clock reads, sleeps, timed waits on descriptors and semaphores. */
static const hook foreign_hooks[] = {
    {"clock_gettime", (void *)hs_clock_gettime},
    {"gettimeofday", (void *)hs_gettimeofday},
    {"time", (void *)hs_time},
    {"nanosleep", (void *)hs_nanosleep},
    {"clock_nanosleep", (void *)hs_clock_nanosleep},
    {"usleep", (void *)hs_usleep},
    {"sleep", (void *)hs_sleep},
    {"poll", (void *)hs_poll},
    {"epoll_wait", (void *)hs_epoll_wait},
    {"select", (void *)hs_select},
    {"sem_clockwait", (void *)hs_sem_clockwait},
    {"sem_timedwait", (void *)hs_sem_timedwait},
    {"sem_post", (void *)hs_sem_post},
    {"dlopen", (void *)hs_dlopen},
    {"dlsym", (void *)hs_dlsym},
    {"pthread_create", (void *)hs_foreign_pthread_create},
};

#define NHOOKS(table) (sizeof table / sizeof table[0])

static void *find_hook(const hook *table, size_t n, const char *name) {
    for (size_t i = 0; i < n; i++) {
        if (strcmp(table[i].name, name) == 0)
            return table[i].fn;
    }
    return NULL;
}

static void *process_hook_for(const char *name) {
    if (strcmp(name, "dlopen") == 0 || strcmp(name, "dlsym") == 0 || strcmp(name, "pthread_create") == 0)
        return NULL;
    return find_hook(foreign_hooks, NHOOKS(foreign_hooks), name);
}

/* ld.so relocates the pointers of a loaded object's dynamic section on most systems; not on all. */
static uintptr_t dyn_ptr(ElfW(Addr) base, ElfW(Addr) p) { return p < base ? base + p : p; }

static void patch_rela(ElfW(Addr) base, const ElfW(Rela) *rel, size_t count, const ElfW(Sym) *symtab,
                       const char *strtab, const hook *table, size_t ntable) {
    long page = sysconf(_SC_PAGESIZE);
    for (size_t i = 0; i < count; i++) {
        unsigned type = (unsigned)ELF64_R_TYPE(rel[i].r_info);
        if (type != R_X86_64_JUMP_SLOT && type != R_X86_64_GLOB_DAT)
            continue;
        const char *name = strtab + symtab[ELF64_R_SYM(rel[i].r_info)].st_name;
        void *fn = find_hook(table, ntable, name);
        if (!fn)
            continue;
        void **slot = (void **)(base + rel[i].r_offset);
        uintptr_t pg = (uintptr_t)slot & ~(uintptr_t)(page - 1);
        if (mprotect((void *)pg, (size_t)page, PROT_READ | PROT_WRITE) != 0)
            continue;
        *slot = fn;
        patched_count++;
    }
}

/* Rewrite the GOT entries of one loaded object that name a function of `table`. */
static void patch_object(struct dl_phdr_info *info, const hook *table, size_t ntable) {
    for (int i = 0; i < info->dlpi_phnum; i++) {
        if (info->dlpi_phdr[i].p_type != PT_DYNAMIC)
            continue;
        const ElfW(Dyn) *dyn = (const ElfW(Dyn) *)(info->dlpi_addr + info->dlpi_phdr[i].p_vaddr);
        const ElfW(Rela) *jmprel = NULL, *rela = NULL;
        size_t jmpsz = 0, relasz = 0;
        const ElfW(Sym) *symtab = NULL;
        const char *strtab = NULL;
        for (; dyn->d_tag != DT_NULL; dyn++) {
            switch (dyn->d_tag) {
            case DT_JMPREL: jmprel = (const ElfW(Rela) *)dyn_ptr(info->dlpi_addr, dyn->d_un.d_ptr); break;
            case DT_PLTRELSZ: jmpsz = dyn->d_un.d_val; break;
            case DT_RELA: rela = (const ElfW(Rela) *)dyn_ptr(info->dlpi_addr, dyn->d_un.d_ptr); break;
            case DT_RELASZ: relasz = dyn->d_un.d_val; break;
            case DT_SYMTAB: symtab = (const ElfW(Sym) *)dyn_ptr(info->dlpi_addr, dyn->d_un.d_ptr); break;
            case DT_STRTAB: strtab = (const char *)dyn_ptr(info->dlpi_addr, dyn->d_un.d_ptr); break;
            }
        }
        if (!symtab || !strtab)
            return;
        if (jmprel)
            patch_rela(info->dlpi_addr, jmprel, jmpsz / sizeof(ElfW(Rela)), symtab, strtab, table, ntable);
        if (rela)
            patch_rela(info->dlpi_addr, rela, relasz / sizeof(ElfW(Rela)), symtab, strtab, table, ntable);
        return;
    }
}

static const char *patch_target;

static int patch_one(struct dl_phdr_info *info, size_t size, void *data) {
    (void)size;
    (void)data;
    if (!info->dlpi_name || !strstr(info->dlpi_name, patch_target))
        return 0;
    patch_object(info, hooks, NHOOKS(hooks));
    return 1;
}

#define MAX_OBJECTS 4096
static uintptr_t patched_objects[MAX_OBJECTS]; /* load addresses of the objects hs_patch_process has patched */
static int n_patched_objects;
static uintptr_t own_base;

/* Which hooks an object of the process gets: the interpreter's, the foreign set, or none (libc and the loader,
 * this shim, MAVSDK's core, which hs_patch gives its own set, and gRPC, whose threads live outside the sim). */
static const hook *table_for(const char *name, size_t *n) {
    static const char *const skip[] = {"linux-vdso", "/libc.so", "/ld-linux", "libpthread.so", "libdl.so", "librt.so",
                                       "/libm.so", "libcmavsdk", "grpc", "libgcc_s"};
    for (size_t i = 0; i < sizeof skip / sizeof skip[0]; i++) {
        if (strstr(name, skip[i]))
            return NULL;
    }
    if (!*name || strstr(name, "libpython") || strstr(name, "/lib-dynload/")) {
        *n = NHOOKS(interp_hooks);
        return interp_hooks;
    }
    *n = NHOOKS(foreign_hooks);
    return foreign_hooks;
}

static int patch_process_one(struct dl_phdr_info *info, size_t size, void *data) {
    (void)size;
    (void)data;
    uintptr_t base = info->dlpi_addr;
    if (base == own_base)
        return 0;
    for (int i = 0; i < n_patched_objects; i++) {
        if (patched_objects[i] == base)
            return 0;
    }
    size_t n = 0;
    const hook *table = table_for(info->dlpi_name ? info->dlpi_name : "", &n);
    if (table)
        patch_object(info, table, n);
    if (n_patched_objects < MAX_OBJECTS && table)
        patched_objects[n_patched_objects++] = base;
    return 0;
}

static int patch_process_locked(void) {
    if (!own_base) {
        Dl_info self;
        if (dladdr((void *)hs_set_wall, &self))
            own_base = (uintptr_t)self.dli_fbase;
    }
    patched_count = 0;
    dl_iterate_phdr(patch_process_one, NULL);
    return patched_count;
}

/* Put the whole process on sim time: the timed lock waits of the interpreter, and the clock, sleeps and timed
 * waits of every other library loaded now or later (see table_for). Returns the GOT entries rewritten now. */
int hs_patch_process(void) {
    pthread_mutex_lock(&patch_mu);
    int n = patch_process_locked();
    pthread_mutex_unlock(&patch_mu);
    return n;
}

/* Route the time, wait, I/O and thread calls of the loaded library whose path contains `target` here.
 * Returns how many GOT entries were rewritten (0: not loaded, or nothing to patch). Idempotent. */
int hs_patch(const char *target) {
    patch_target = target;
    patched_count = 0;
    dl_iterate_phdr(patch_one, NULL);
    return patched_count;
}

/* A process forked from the mission without exec (multiprocessing's fork) becomes a child of it: simchild.c's
 * functions (loaded from `path`) replace every hook of this process, through the same GOTs. 1 when joined. */
static const char *const child_names[] = {
    "clock_gettime", "gettimeofday", "time", "nanosleep", "clock_nanosleep", "usleep", "sleep", "poll", "ppoll",
    "epoll_wait", "epoll_pwait", "select", "read", "recv", "recvfrom", "accept", "wait4", "waitpid", "fork", "vfork",
    "posix_spawn", "posix_spawnp", "pthread_create"};
static hook child_hooks[sizeof child_names / sizeof child_names[0]];
static size_t n_child_hooks;
static uintptr_t child_base;

static int patch_child_one(struct dl_phdr_info *info, size_t size, void *data) {
    (void)size;
    (void)data;
    const char *name = info->dlpi_name ? info->dlpi_name : "";
    static const char *const skip[] = {"linux-vdso", "/libc.so", "/ld-linux", "libpthread.so", "libdl.so"};
    for (size_t i = 0; i < sizeof skip / sizeof skip[0]; i++) {
        if (strstr(name, skip[i]))
            return 0;
    }
    if (info->dlpi_addr == own_base || info->dlpi_addr == child_base)
        return 0;
    patch_object(info, child_hooks, n_child_hooks);
    return 0;
}

int hs_become_child(const char *path) {
    void *h = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!h)
        return 0;
    int (*start)(void) = (int (*)(void))dlsym(h, "hs_child_start");
    if (!start || !start())
        return 0;
    __atomic_store_n(&active, 0, __ATOMIC_RELEASE); /* the mission's side of the shim is not this process's */
    size_t n = 0;
    for (size_t i = 0; i < sizeof child_names / sizeof child_names[0]; i++) {
        void *fn = dlsym(h, child_names[i]);
        if (fn)
            child_hooks[n++] = (hook){child_names[i], fn};
    }
    Dl_info info;
    if (dladdr((void *)start, &info))
        child_base = (uintptr_t)info.dli_fbase;
    if (!own_base && dladdr((void *)hs_set_wall, &info))
        own_base = (uintptr_t)info.dli_fbase;
    n_child_hooks = n;
    patched_count = 0;
    dl_iterate_phdr(patch_child_one, NULL);
    return 1;
}
