/*
 * simtime.c: a C library's threads on the simulation clock (MAVSDK's libcmavsdk.so in a mission process).
 *
 * harness.simclock.shim builds it once per machine (cc -O2 -shared -fPIC, with simtime_*.c: their parts are listed
 * in simtime.h) and harness.simclock.native loads it with ctypes. This file is its core: the state, the thread
 * states, the wait, the gate's release, the idle count, and the threads it tracks.
 * hs_patch() rewrites the GOT entries of one loaded library (the one whose path contains a given string) so
 * that its calls to the clock, sleeps, condition variables, futexes, poll/epoll/select, blocking receives,
 * timerfds and pthread_create come here instead of to libc; hs_patch_process() puts the C-level waits of the rest
 * of the process on sim time, hs_children() its child processes (simchild.c).
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
#include "simtime.h"

pthread_mutex_t mu = PTHREAD_MUTEX_INITIALIZER;
pthread_cond_t changed = PTHREAD_COND_INITIALIZER;
uint64_t generation;
int64_t now_ns;
int64_t epoch_ns;
int gate_open;
int closed;
uint64_t sent;
tstate *threads;
simtimer timers[MAX_TIMERS];
int thread_count;
FILE *trace;
int active;
__thread int wall_thread;
int want_fd = -1;
static pthread_key_t tkey;
static pthread_once_t tkey_once = PTHREAD_ONCE_INIT;

/* -- thread states (mu held) ------------------------------------------------------------------------- */

void hs__poke_locked(void) {
    generation++;
    pthread_cond_broadcast(&changed);
}

/* Mark a waiting thread busy and let it run; gated: outside phase 0 it is left pending. */
void hs__release_locked(tstate *t, int timed_out) {
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
        hs__close_child_fds_locked(t);
        hs__tell_child(t, 'G');
        return;
    }
    wake_fd(t->evfd);
    if (!t->tracked)
        hs__poke_locked(); /* a script thread (a blocking call, destroy) runs again: the clock thread must see it */
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
    hs__poke_locked();
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

tstate *hs__me(void) {
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


/* Block the calling thread (idle) until released: by a wake on `addr`, its descriptors becoming ready,
 * sim time reaching `deadline`, or the end of the run. `fds` are polled, never consumed. Returns 1 when
 * the wait timed out. `mu` must NOT be held; `locked` says whether the caller registered under mu already
 * (cond/futex waits register atomically with their own checks). */
int hs__sim_wait_in(tstate *t, const struct pollfd *fds, int nfds, int64_t deadline, const void *addr, int locked,
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
        hs__release_locked(t, !closed);
    /* The clock thread looks again only when this can end the library's turn or the phase: the library's last
     * busy thread waits, or a thread of the script's (a caller) does. Waking it at every wait of every thread
     * made it look ~30 times a phase. */
    if (!t->tracked || hs__busy_locked() == 0)
        hs__poke_locked();
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
            hs__release_locked(t, 0);
            if (t->pending)
                hs__poke_locked();
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


/* Release every waiting thread whose descriptors are ready (mu held). */
int hs__release_ready_locked(void) {
    int n = 0;
    for (tstate *th = threads; th; th = th->next) {
        if (!th->waiting || th->released || !th->nfds)
            continue;
        struct pollfd p[MAX_FDS];
        memcpy(p, th->fds, (size_t)th->nfds * sizeof *p);
        if (real_poll(p, (nfds_t)th->nfds, 0) != 0) {
            hs__release_locked(th, 0);
            n++;
        }
    }
    return n;
}

int hs__busy_locked(void) {
    int n = 0;
    for (tstate *th = threads; th; th = th->next) {
        if (th->tracked && (!th->waiting || th->released))
            n++;
    }
    return n;
}

/* -- the threads it tracks ------------------------------------------------------------------------- */

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

int hs_pthread_create(pthread_t *th, const pthread_attr_t *attr, void *(*fn)(void *), void *arg) {
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

/* A thread a C extension starts (libzmq's I/O threads) counts in the idle decision like MAVSDK's, from its start. */
int hs_foreign_pthread_create(pthread_t *th, const pthread_attr_t *attr, void *(*fn)(void *), void *arg) {
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
