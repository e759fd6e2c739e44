/*
 * simtime_clock.c: the hooks of time and synchronisation (see simtime.c): clock reads, sleeps, condition variables,
 * futexes, semaphores and timerfds, on the sim clock.
 */
#include "simtime.h"

#define MAX_CONDS 1024


/* asio asks for "fire now" when its next timer is less than a microsecond away (it truncates to whole
 * microseconds), then finds no timer due and asks again: on a clock that moves that ends within a microsecond,
 * on sim time (frozen within a phase) it never would. After this many in one phase, the timer fires at the
 * next phase instead: time passes, as it would. */
#define FIRE_NOW_PER_PHASE 16

typedef struct {
    const void *cond;
    clockid_t clock;
} condclock;

static condclock condclocks[MAX_CONDS];
static int sem_waiters; /* threads inside a semaphore wait here: sem_post looks for them only then */

/* -1 with EINTR when the thread's last wait was ended for a signal (hs_interrupt), else 0. */
static int interrupted(const tstate *t) {
    if (!t->interrupted)
        return 0;
    errno = EINTR;
    return -1;
}

/* An absolute time on clock `c` as a sim deadline. */
static int64_t abs_deadline(clockid_t c, const struct timespec *abst) {
    if (!abst)
        return NO_DEADLINE;
    int64_t v = ts_ns(abst);
    return is_wall_clock(c) ? v - epoch_ns : v;
}

/* -- clocks and sleeps ------------------------------------------------------------------------------- */

int hs_clock_gettime(clockid_t c, struct timespec *ts) {
    int64_t v;
    if (!on_sim())
        return real_clock_gettime(c, ts);
    if (is_sim_clock(c))
        v = sim_now();
    else if (is_wall_clock(c))
        v = epoch_ns + sim_now();
    else
        return real_clock_gettime(c, ts);
    ns_ts(v, ts);
    return 0;
}

int hs_gettimeofday(struct timeval *tv, void *tz) {
    if (!on_sim())
        return gettimeofday(tv, tz);
    if (tv) {
        int64_t v = epoch_ns + sim_now();
        tv->tv_sec = v / 1000000000LL;
        tv->tv_usec = (v % 1000000000LL) / 1000;
    }
    return 0;
}

time_t hs_time(time_t *out) {
    if (!on_sim())
        return time(out);
    time_t v = (time_t)((epoch_ns + sim_now()) / 1000000000LL);
    if (out)
        *out = v;
    return v;
}

int hs_nanosleep(const struct timespec *req, struct timespec *rem) {
    if (!on_sim())
        return nanosleep(req, rem);
    if (rem)
        rem->tv_sec = rem->tv_nsec = 0;
    if (!req || ts_ns(req) <= 0)
        return 0;
    tstate *t = hs__me();
    sim_wait(t, NULL, 0, add_ns(sim_now(), ts_ns(req)), NULL, 0);
    return interrupted(t);
}

int hs_clock_nanosleep(clockid_t c, int flags, const struct timespec *req, struct timespec *rem) {
    if (!on_sim() || !(is_sim_clock(c) || is_wall_clock(c)))
        return clock_nanosleep(c, flags, req, rem);
    if (rem && !(flags & TIMER_ABSTIME))
        rem->tv_sec = rem->tv_nsec = 0;
    int64_t deadline = (flags & TIMER_ABSTIME) ? abs_deadline(c, req) : add_ns(sim_now(), ts_ns(req));
    if (!(flags & TIMER_ABSTIME) && ts_ns(req) <= 0)
        return 0;
    tstate *t = hs__me();
    sim_wait(t, NULL, 0, deadline, NULL, 0);
    return t->interrupted ? EINTR : 0;
}

int hs_usleep(useconds_t us) {
    if (!on_sim())
        return usleep(us);
    tstate *t = hs__me();
    if (us > 0)
        sim_wait(t, NULL, 0, add_ns(sim_now(), (int64_t)us * 1000), NULL, 0);
    return interrupted(t);
}

unsigned int hs_sleep(unsigned int s) {
    if (!on_sim())
        return sleep(s);
    if (s > 0)
        sim_wait(hs__me(), NULL, 0, add_ns(sim_now(), (int64_t)s * 1000000000LL), NULL, 0);
    return 0;
}

/* -- condition variables and futexes --------------------------------------------------------------- */

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

int hs_cond_init(pthread_cond_t *c, const pthread_condattr_t *a) {
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

int hs_cond_destroy(pthread_cond_t *c) {
    pthread_mutex_lock(&mu);
    for (int i = 0; i < MAX_CONDS; i++) {
        if (condclocks[i].cond == c)
            condclocks[i].cond = NULL;
    }
    pthread_mutex_unlock(&mu);
    return pthread_cond_destroy(c);
}

static int cond_wait(pthread_cond_t *c, pthread_mutex_t *m, int64_t deadline) {
    tstate *t = hs__me();
    pthread_mutex_lock(&mu); /* registered while `m` is still held: a signal after this finds us */
    pthread_mutex_unlock(m);
    int timed_out = sim_wait(t, NULL, 0, deadline, c, 1);
    pthread_mutex_lock(m);
    return timed_out && deadline != NO_DEADLINE ? ETIMEDOUT : 0; /* an untimed wait never times out */
}

int hs_cond_wait(pthread_cond_t *c, pthread_mutex_t *m) { return cond_wait(c, m, NO_DEADLINE); }

int hs_cond_timedwait(pthread_cond_t *c, pthread_mutex_t *m, const struct timespec *abst) {
    return cond_wait(c, m, abs_deadline(cond_clock(c), abst));
}

static int wake_addr(const void *addr) {
    int n = 0;
    pthread_mutex_lock(&mu);
    for (tstate *t = threads; t; t = t->next) {
        if (t->waiting && !t->released && t->addr == addr) {
            hs__release_locked(t, 0);
            n++;
        }
    }
    pthread_mutex_unlock(&mu); /* a release makes the phase busier: nothing for the clock thread to look at */
    return n;
}

int hs_cond_signal(pthread_cond_t *c) {
    wake_addr(c);
    return pthread_cond_broadcast(c);
}

int hs_cond_broadcast(pthread_cond_t *c) {
    wake_addr(c);
    return pthread_cond_broadcast(c);
}

static long futex_wait(uint32_t *addr, uint32_t val, int64_t deadline) {
    tstate *t = hs__me();
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

long hs_syscall(long nr, long a1, long a2, long a3, long a4, long a5, long a6) {
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

/* -- semaphores (the interpreter's timed lock waits) ------------------------------------------------ */

/* A timed semaphore wait (CPython's Lock.acquire(timeout=...), SimpleQueue.get(timeout=...)): the deadline was
 * computed on the real clock (the interpreter reads it unpatched), so what is left of it starts now in sim time.
 * The thread waits on the semaphore's address; hs_sem_post releases it. */
static int sem_wait_sim(sem_t *s, int64_t remaining) {
    tstate *t = hs__me();
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

int hs_sem_clockwait(sem_t *s, clockid_t c, const struct timespec *abst) {
    if (!on_sim())
        return sem_clockwait(s, c, abst);
    return sem_wait_sim(s, remaining_ns(c, abst));
}

int hs_sem_timedwait(sem_t *s, const struct timespec *abst) {
    if (!on_sim())
        return sem_timedwait(s, abst);
    return sem_wait_sim(s, remaining_ns(CLOCK_REALTIME, abst));
}

int hs_sem_post(sem_t *s) {
    int r = sem_post(s);
    if (__atomic_load_n(&sem_waiters, __ATOMIC_SEQ_CST) > 0)
        wake_addr(s);
    return r;
}

/* -- timerfds --------------------------------------------------------------------------------------- */

/* timerfds are eventfds (a read gives the expirations, as a timerfd's does) written when sim time passes. */
int hs_timerfd_create(int clockid, int flags) {
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

void hs__fire_due_timers_locked(void) {
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

int hs_timerfd_settime(int fd, int flags, const struct itimerspec *nv, struct itimerspec *old) {
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
        hs__fire_due_timers_locked();
    hs__poke_locked();
    pthread_mutex_unlock(&mu);
    return 0;
}

int hs_close_fd(int fd) {
    pthread_mutex_lock(&mu);
    for (int i = 0; i < MAX_TIMERS; i++) {
        if (timers[i].fd == fd + 1)
            timers[i].fd = 0;
    }
    pthread_mutex_unlock(&mu);
    return close(fd);
}
