/*
 * simtime_control.c: the clock thread's side of the shim (see simtime.c), called through ctypes
 * (harness.simclock.native): a phase begins (hs_begin), ends when it can (hs_try_close), and what the runtime
 * asks about the library's threads, one by one or in one snapshot (hs_snapshot).
 */
#include "simtime.h"

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
            hs__release_locked(th, 0);
    }
    pthread_mutex_unlock(&mu);
}

/* Release every waiting thread whose descriptors are ready now; how many. */
int hs_release_ready(void) {
    pthread_mutex_lock(&mu);
    int n = hs__release_ready_locked();
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
        if (hs__busy_locked() == 0 && hs__release_ready_locked() == 0) {
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
    int n = hs__busy_locked();
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
    if (generation == g && hs__busy_locked() == 0 && hs__release_ready_locked() == 0) {
        int due = 0;
        hs__fire_due_timers_locked();
        due = hs__release_ready_locked(); /* a fired timerfd makes its epoll readable */
        if (!due) {
            for (tstate *th = threads; th; th = th->next) {
                if (th->waiting && !th->released && th->deadline <= now_ns) {
                    hs__release_locked(th, 1);
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
static int64_t next_deadline_locked(void) {
    int64_t d = NO_DEADLINE;
    for (tstate *th = threads; th; th = th->next) {
        if (th->waiting && !th->released && th->deadline < d)
            d = th->deadline;
    }
    for (int i = 0; i < MAX_TIMERS; i++) {
        if (timers[i].fd && timers[i].deadline < d)
            d = timers[i].deadline;
    }
    return d;
}

int64_t hs_next_deadline(void) {
    pthread_mutex_lock(&mu);
    int64_t d = next_deadline_locked();
    pthread_mutex_unlock(&mu);
    return d;
}

/* Whether some waiting thread waits for descriptors (MAVLink arrives at every phase: no lookahead). */
static int waits_for_io_locked(void) {
    int r = 0;
    for (tstate *th = threads; th; th = th->next)
        r |= th->waiting && th->nfds > 0;
    return r;
}

int hs_waits_for_io(void) {
    pthread_mutex_lock(&mu);
    int r = waits_for_io_locked();
    pthread_mutex_unlock(&mu);
    return r;
}

/* The state of thread `self` (a pthread_t, Python's thread ident): the first in the list; NULL when it has none. */
static const tstate *thread_of_locked(uint64_t self) {
    for (tstate *th = threads; th; th = th->next) {
        if ((uint64_t)th->self == self)
            return th;
    }
    return NULL;
}

static int thread_waiting_locked(const tstate *th) { return th && th->waiting && !th->released; }

/* 1 when thread `self` (a pthread_t, Python's thread ident) is inside a wait that has not ended. */
int hs_thread_waiting(uint64_t self) {
    pthread_mutex_lock(&mu);
    int r = thread_waiting_locked(thread_of_locked(self));
    pthread_mutex_unlock(&mu);
    return r;
}

/* hs_generation, hs_busy, hs_sent, hs_next_deadline and hs_waits_for_io in one look, under `mu`: one state, where
 * five calls could each see another. `waiting` gets (up to `cap` of) the threads for which hs_thread_waiting is 1;
 * returns how many there are (out->nwaiting; more than `cap`: ask again with room for them). */
int hs_snapshot(hs_state *out, uint64_t *waiting, int cap) {
    pthread_mutex_lock(&mu);
    out->generation = generation;
    out->busy = hs__busy_locked();
    out->sent = __atomic_load_n(&sent, __ATOMIC_ACQUIRE);
    out->next_deadline = next_deadline_locked();
    out->waits_for_io = waits_for_io_locked();
    int n = 0;
    for (tstate *th = threads; th; th = th->next) {
        if (th->self && thread_waiting_locked(th) && thread_of_locked((uint64_t)th->self) == th) {
            if (n < cap)
                waiting[n] = (uint64_t)th->self;
            n++;
        }
    }
    out->nwaiting = n;
    pthread_mutex_unlock(&mu);
    return n;
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
    hs__poke_locked();
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
            hs__release_locked(th, 1);
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


/* The calling thread is the harness's own (the clock thread), or becomes so (the main thread once the script has
 * ended): its clock and waits stay real whatever code it calls. */
void hs_set_wall(int wall) { wall_thread = wall; }

/* End the wait of thread `self` for a signal (the runtime's signal timer): its call returns EINTR. 1 if it waited. */
int hs_interrupt(uint64_t self) {
    pthread_mutex_lock(&mu);
    int r = 0;
    for (tstate *th = threads; th; th = th->next) {
        if ((uint64_t)th->self == self && th->waiting && !th->released) {
            th->interrupted = 1;
            hs__release_locked(th, 0);
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
