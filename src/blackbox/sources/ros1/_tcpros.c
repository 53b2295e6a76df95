/*
 * The native TCPROS receive loop (Linux): epoll, recvmsg and the splitting of length-prefixed
 * messages run here with the interpreter lock released, so a message costs the kernel's work
 * and a few counters, not an interpreter wake-up.
 *
 * Why it exists: in Python every wake-up of the reader thread costs 15-150 us of interpreter
 * time however little it reads, and a rospy publisher writes each message alone, so a wake-up
 * per message is the norm (docs/benchmarks.md). Here one call of Engine.poll() waits, reads
 * and splits for up to a hand-over interval and returns to Python once, with one record per
 * receive: (sid, count, bytes, kernel time), the body of each message of a decoded topic, the
 * first message of a connection and connections that ended (with the same reasons as the
 * Python reader, stream_reader.py, which stays as the fallback and the reference).
 *
 * Threading: add()/remove()/poll() are called by one reader thread; idle() may be called by
 * any thread (it holds the interpreter lock, and the stream table only changes in add() and
 * remove(), which hold it too and never run during poll()).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <structmember.h>

#include <errno.h>
#include <stdint.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <unistd.h>
#include <time.h>

#define SCRATCH_BYTES (256 * 1024)
#define SKIP_BYTES (4 * 1024 * 1024)
#define LOWAT_CAP SKIP_BYTES
#define READS_PER_WAKEUP 16
#define MAX_EVENTS 64
#define REASON_BYTES 200

enum { REC_ARRIVALS = 0, REC_BODY = 1, REC_FIRST = 2, REC_CLOSED = 3 };

typedef struct {
    int kind;
    uint32_t sid;
    uint64_t count;
    uint64_t bytes;
    double time;
    char *body; /* REC_BODY: the message; REC_CLOSED: the reason (malloc'ed, freed here) */
    const void *stream; /* the Stream: alive until poll() returns (only remove() frees it) */
} Record;

typedef struct {
    uint32_t sid;
    int fd;
    uint64_t max_bytes;
    int keep;         /* decoded topic: keep each body */
    int closed;
    unsigned char lenbuf[4];
    int lenfill;
    int64_t remaining; /* -1: reading a length prefix */
    uint64_t size;
    char *body;
    uint64_t messages;
    uint64_t pending;
    uint64_t pending_bytes;
    int lowat;
    double last_rx;      /* CLOCK_MONOTONIC seconds, as time.monotonic() */
    PyObject *topic;     /* str or NULL: the batch objects' topic (strong reference) */
    PyObject *publisher; /* str or NULL */
} Stream;

/* Where ArrivalBatch keeps each of its slots (byte offsets into the object). */
enum { SLOT_TIME, SLOT_TOPIC, SLOT_PUBLISHER, SLOT_COUNT, SLOT_BYTES, SLOTS };
static const char *const slot_names[SLOTS] = {"time", "topic", "publisher", "count", "bytes"};

typedef struct {
    PyObject_HEAD
    int epfd;
    int wake_fd;
    Stream **streams;
    Py_ssize_t nstreams, capstreams;
    Record *recs;
    Py_ssize_t nrecs, caprecs;
    int compact;
    int oom;
    double woke; /* when the last round began: coalescing spans poll() calls */
    unsigned char *scratch;
    void *skip;
    PyTypeObject *batch_type;   /* NULL: records stay tuples */
    Py_ssize_t slot_offset[SLOTS];
    Py_ssize_t objects;         /* records of the last poll that are ready-made objects */
} Engine;

static double mono_now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

static double wall_now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

static Record *push(Engine *e, int kind, Stream *s) {
    if (e->nrecs == e->caprecs) {
        Py_ssize_t cap = e->caprecs ? e->caprecs * 2 : 256;
        Record *grown = realloc(e->recs, (size_t)cap * sizeof(Record));
        if (grown == NULL) {
            e->oom = 1;
            return NULL;
        }
        e->recs = grown;
        e->caprecs = cap;
    }
    Record *r = &e->recs[e->nrecs++];
    r->kind = kind;
    r->sid = s->sid;
    r->stream = s;
    r->count = 0;
    r->bytes = 0;
    r->time = 0.0;
    r->body = NULL;
    return r;
}

static void close_stream(Engine *e, Stream *s, const char *reason) {
    s->closed = 1;
    epoll_ctl(e->epfd, EPOLL_CTL_DEL, s->fd, NULL);
    free(s->body);
    s->body = NULL;
    Record *r = push(e, REC_CLOSED, s);
    if (r != NULL) {
        r->body = strdup(reason);
        r->count = s->messages;
    }
}

static void flush_pending(Engine *e, Stream *s, double now) {
    Record *r = push(e, REC_ARRIVALS, s);
    if (r != NULL) {
        r->count = s->pending;
        r->bytes = s->pending_bytes;
        r->time = now;
    }
    s->pending = 0;
    s->pending_bytes = 0;
}

static void complete(Engine *e, Stream *s, double now) {
    s->remaining = -1;
    s->messages += 1;
    if (s->messages == 1)
        push(e, REC_FIRST, s);
    if (s->keep) {
        Record *r = push(e, REC_BODY, s);
        if (r != NULL) {
            r->bytes = s->size;
            r->time = now;
            r->body = s->body;
        } else {
            free(s->body);
        }
        s->body = NULL;
    } else if (e->compact) {
        s->pending += 1;
        s->pending_bytes += s->size;
    } else {
        Record *r = push(e, REC_ARRIVALS, s);
        if (r != NULL) {
            r->count = 1;
            r->bytes = s->size;
            r->time = now;
        }
    }
}

/* A new length prefix: refuse one over the cap, else start the body. 0 when closed. */
static int start_message(Engine *e, Stream *s, uint32_t size) {
    if ((uint64_t)size > s->max_bytes) {
        char reason[REASON_BYTES];
        snprintf(reason, sizeof reason,
                 "message length prefix of %u bytes exceeds the cap of %llu bytes",
                 size, (unsigned long long)s->max_bytes);
        close_stream(e, s, reason); /* Python adds the topic and the explanation */
        return 0;
    }
    s->size = size;
    s->remaining = size;
    if (s->keep) {
        s->body = malloc(size ? size : 1);
        if (s->body == NULL) {
            close_stream(e, s, "out of memory for a message body");
            return 0;
        }
    }
    return 1;
}

static uint32_t le32(const unsigned char *p) {
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) |
           ((uint32_t)p[3] << 24);
}

/* Split n bytes of the scratch buffer into messages (as TcprosReader._split). */
static void split(Engine *e, Stream *s, Py_ssize_t n, double now) {
    const unsigned char *buf = e->scratch;
    Py_ssize_t pos = 0;
    while (pos < n) {
        if (s->remaining < 0) {
            uint32_t size;
            if (s->lenfill == 0 && n - pos >= 4) {
                size = le32(buf + pos);
                pos += 4;
            } else {
                Py_ssize_t take = 4 - s->lenfill;
                if (take > n - pos)
                    take = n - pos;
                memcpy(s->lenbuf + s->lenfill, buf + pos, (size_t)take);
                s->lenfill += (int)take;
                pos += take;
                if (s->lenfill < 4)
                    break;
                size = le32(s->lenbuf);
                s->lenfill = 0;
            }
            if (!start_message(e, s, size))
                return;
            if (size)
                continue;
        } else {
            Py_ssize_t take = s->remaining < n - pos ? (Py_ssize_t)s->remaining : n - pos;
            if (s->body != NULL)
                memcpy(s->body + (s->size - (uint64_t)s->remaining), buf + pos, (size_t)take);
            pos += take;
            s->remaining -= take;
            if (s->remaining)
                continue;
        }
        complete(e, s, now);
    }
}

/* One recvmsg; > 0 bytes (or bytes dropped with MSG_TRUNC), 0 nothing there or closed. */
static Py_ssize_t receive(Engine *e, Stream *s, void *into, size_t len, int flags, double *now) {
    struct iovec iov = {into, len};
    union {
        char buf[CMSG_SPACE(sizeof(struct timespec))];
        struct cmsghdr align;
    } control;
    struct msghdr msg;
    memset(&msg, 0, sizeof msg);
    msg.msg_iov = &iov;
    msg.msg_iovlen = 1;
    msg.msg_control = control.buf;
    msg.msg_controllen = sizeof control.buf;
    ssize_t n;
    do {
        n = recvmsg(s->fd, &msg, flags | MSG_DONTWAIT);
    } while (n < 0 && errno == EINTR);
    if (n < 0) {
        if (errno == EAGAIN || errno == EWOULDBLOCK)
            return 0;
        char reason[REASON_BYTES];
        snprintf(reason, sizeof reason, "connection error: [Errno %d] %s", errno,
                 strerror(errno));
        close_stream(e, s, reason);
        return 0;
    }
    if (n == 0) {
        close_stream(e, s, "publisher closed the connection");
        return 0;
    }
    *now = 0.0;
    for (struct cmsghdr *c = CMSG_FIRSTHDR(&msg); c != NULL; c = CMSG_NXTHDR(&msg, c)) {
        if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SCM_TIMESTAMPNS &&
            c->cmsg_len >= CMSG_LEN(sizeof(struct timespec))) {
            struct timespec ts;
            memcpy(&ts, CMSG_DATA(c), sizeof ts);
            *now = (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
        }
    }
    if (*now == 0.0)
        *now = wall_now();
    return (Py_ssize_t)n;
}

/* Ask to be woken only once the rest of the current message is there (SO_RCVLOWAT). */
static void wake_at(Stream *s) {
    int want = s->remaining > 0 ? (int)(s->remaining < LOWAT_CAP ? s->remaining : LOWAT_CAP)
                                : (s->lenfill ? 4 - s->lenfill : 1);
    if (want != s->lowat && setsockopt(s->fd, SOL_SOCKET, SO_RCVLOWAT, &want, sizeof want) == 0)
        s->lowat = want;
}

static void read_stream(Engine *e, Stream *s) {
    double now;
    for (int i = 0; i < READS_PER_WAKEUP && !s->closed; i++) {
        if (s->body == NULL && s->remaining > 0) {
            /* the body of a timing-only message: the kernel drops it uncopied */
            size_t len = s->remaining < SKIP_BYTES ? (size_t)s->remaining : SKIP_BYTES;
            Py_ssize_t n = receive(e, s, e->skip, len, MSG_TRUNC, &now);
            if (n <= 0)
                break;
            s->remaining -= n;
            if (s->remaining == 0) {
                complete(e, s, now);
                if (s->pending)
                    flush_pending(e, s, now);
            }
            continue;
        }
        Py_ssize_t n = receive(e, s, e->scratch, SCRATCH_BYTES, 0, &now);
        if (n <= 0)
            break;
        split(e, s, n, now);
        if (s->pending)
            flush_pending(e, s, now);
        if (s->closed || n < SCRATCH_BYTES)
            break;
    }
    if (!s->closed) {
        s->last_rx = mono_now();
        wake_at(s);
    }
}

/* Frees a stream (the interpreter lock is held: it drops the name references). */
static void free_stream(Stream *s) {
    free(s->body);
    Py_XDECREF(s->topic);
    Py_XDECREF(s->publisher);
    free(s);
}

static Stream *find(Engine *e, uint32_t sid, Py_ssize_t *index) {
    for (Py_ssize_t i = 0; i < e->nstreams; i++)
        if (e->streams[i]->sid == sid) {
            if (index != NULL)
                *index = i;
            return e->streams[i];
        }
    return NULL;
}

/* ---- Python type ----------------------------------------------------------------------- */

/*
 * The offsets of batch_type's slots: it must be a class whose five attributes are plain
 * __slots__ (member descriptors holding objects), as events.ArrivalBatch is; anything else is
 * refused at construction, so a changed event class fails loudly instead of being written to.
 */
static int resolve_slots(Engine *self, PyObject *batch_type) {
    if (!PyType_Check(batch_type)) {
        PyErr_SetString(PyExc_TypeError, "batch_type must be a class");
        return -1;
    }
    PyTypeObject *type = (PyTypeObject *)batch_type;
    if (type->tp_alloc == NULL) {
        PyErr_SetString(PyExc_TypeError, "batch_type cannot be allocated");
        return -1;
    }
    for (int i = 0; i < SLOTS; i++) {
        PyObject *descr = PyObject_GetAttrString(batch_type, slot_names[i]);
        if (descr == NULL)
            return -1;
        int ok = Py_IS_TYPE(descr, &PyMemberDescr_Type);
        if (ok) {
            PyMemberDef *m = ((PyMemberDescrObject *)descr)->d_member;
            ok = m->type == T_OBJECT_EX && !(m->flags & READONLY);
            self->slot_offset[i] = m->offset;
        }
        Py_DECREF(descr);
        if (!ok) {
            PyErr_Format(PyExc_TypeError, "batch_type.%s is not a plain __slots__ attribute",
                         slot_names[i]);
            return -1;
        }
    }
    Py_INCREF(batch_type);
    self->batch_type = type;
    return 0;
}

static int Engine_init(Engine *self, PyObject *args, PyObject *kwds) {
    static char *kwlist[] = {"wake_fd", "compact", "batch_type", NULL};
    int wake_fd, compact = 0;
    PyObject *batch_type = Py_None;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "i|pO", kwlist, &wake_fd, &compact,
                                     &batch_type))
        return -1;
    if (batch_type != Py_None && resolve_slots(self, batch_type) < 0)
        return -1;
    self->compact = compact;
    self->wake_fd = wake_fd;
    self->epfd = epoll_create1(EPOLL_CLOEXEC);
    if (self->epfd < 0) {
        PyErr_SetFromErrno(PyExc_OSError);
        return -1;
    }
    struct epoll_event ev = {.events = EPOLLIN, .data = {.ptr = NULL}};
    if (epoll_ctl(self->epfd, EPOLL_CTL_ADD, wake_fd, &ev) < 0) {
        PyErr_SetFromErrno(PyExc_OSError);
        return -1;
    }
    self->scratch = malloc(SCRATCH_BYTES);
    /* never written for TCP (MSG_TRUNC), so the mapping costs no memory */
    self->skip = mmap(NULL, SKIP_BYTES, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS,
                      -1, 0);
    if (self->scratch == NULL || self->skip == MAP_FAILED) {
        self->skip = NULL;
        PyErr_NoMemory();
        return -1;
    }
    return 0;
}

static void Engine_dealloc(Engine *self) {
    for (Py_ssize_t i = 0; i < self->nstreams; i++)
        free_stream(self->streams[i]);
    free(self->streams);
    Py_XDECREF((PyObject *)self->batch_type);
    for (Py_ssize_t i = 0; i < self->nrecs; i++)
        free(self->recs[i].body);
    free(self->recs);
    free(self->scratch);
    if (self->skip != NULL)
        munmap(self->skip, SKIP_BYTES);
    if (self->epfd > 0)
        close(self->epfd);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static PyObject *Engine_add(Engine *self, PyObject *args) {
    unsigned int sid;
    int fd, keep;
    unsigned long long max_bytes;
    PyObject *topic = NULL, *publisher = NULL;
    if (!PyArg_ParseTuple(args, "IiKp|UU", &sid, &fd, &max_bytes, &keep, &topic, &publisher))
        return NULL;
    if (find(self, sid, NULL) != NULL) {
        PyErr_Format(PyExc_ValueError, "stream %u is already read", sid);
        return NULL;
    }
    if (self->nstreams == self->capstreams) {
        Py_ssize_t cap = self->capstreams ? self->capstreams * 2 : 16;
        Stream **grown = realloc(self->streams, (size_t)cap * sizeof(Stream *));
        if (grown == NULL)
            return PyErr_NoMemory();
        self->streams = grown;
        self->capstreams = cap;
    }
    Stream *s = calloc(1, sizeof(Stream));
    if (s == NULL)
        return PyErr_NoMemory();
    s->sid = sid;
    s->fd = fd;
    s->max_bytes = max_bytes;
    s->keep = keep;
    s->remaining = -1;
    s->lowat = 1;
    s->last_rx = mono_now();
    if (topic != NULL && publisher != NULL) {
        Py_INCREF(topic);
        Py_INCREF(publisher);
        s->topic = topic;
        s->publisher = publisher;
    }
    struct epoll_event ev = {.events = EPOLLIN, .data = {.ptr = s}};
    if (epoll_ctl(self->epfd, EPOLL_CTL_ADD, fd, &ev) < 0) {
        free_stream(s);
        return PyErr_SetFromErrno(PyExc_OSError);
    }
    self->streams[self->nstreams++] = s;
    Py_RETURN_NONE;
}

static PyObject *Engine_remove(Engine *self, PyObject *args) {
    unsigned int sid;
    if (!PyArg_ParseTuple(args, "I", &sid))
        return NULL;
    Py_ssize_t i;
    Stream *s = find(self, sid, &i);
    if (s == NULL)
        return PyLong_FromLong(-1);
    if (!s->closed)
        epoll_ctl(self->epfd, EPOLL_CTL_DEL, s->fd, NULL);
    unsigned long long messages = s->messages;
    free_stream(s);
    self->streams[i] = self->streams[--self->nstreams];
    return PyLong_FromUnsignedLongLong(messages);
}

static PyObject *Engine_idle(Engine *self, PyObject *Py_UNUSED(ignored)) {
    PyObject *out = PyDict_New();
    if (out == NULL)
        return NULL;
    double now = mono_now();
    for (Py_ssize_t i = 0; i < self->nstreams; i++) {
        Stream *s = self->streams[i];
        if (s->closed)
            continue;
        PyObject *k = PyLong_FromUnsignedLong(s->sid);
        PyObject *v = PyFloat_FromDouble(now - s->last_rx);
        if (k == NULL || v == NULL || PyDict_SetItem(out, k, v) < 0) {
            Py_XDECREF(k);
            Py_XDECREF(v);
            Py_DECREF(out);
            return NULL;
        }
        Py_DECREF(k);
        Py_DECREF(v);
    }
    return out;
}

static void sleep_seconds(double seconds) {
    struct timespec ts = {(time_t)seconds, (long)((seconds - (double)(time_t)seconds) * 1e9)};
    while (nanosleep(&ts, &ts) < 0 && errno == EINTR) {
    }
}

static PyObject *arrivals_tuple(const Record *r) {
    PyObject *t = PyTuple_New(5);
    if (t == NULL)
        return NULL;
    PyObject *items[5] = {PyLong_FromLong(r->kind), PyLong_FromUnsignedLong(r->sid),
                          PyLong_FromUnsignedLongLong(r->count),
                          PyLong_FromUnsignedLongLong(r->bytes), PyFloat_FromDouble(r->time)};
    for (int i = 0; i < 5; i++) {
        if (items[i] == NULL) {
            for (int k = 0; k < 5; k++)
                Py_XDECREF(items[k]);
            Py_DECREF(t);
            return NULL;
        }
    }
    for (int i = 0; i < 5; i++)
        PyTuple_SET_ITEM(t, i, items[i]);
    return t;
}

/*
 * One ArrivalBatch made without its __init__: allocated by the class and its five slots filled
 * directly (the class was checked in resolve_slots), exactly what ArrivalBatch(time, topic,
 * publisher, count, bytes) would hold.
 */
static PyObject *arrivals_object(Engine *self, const Record *r) {
    const Stream *s = r->stream;
    PyTypeObject *type = self->batch_type;
    PyObject *values[SLOTS] = {PyFloat_FromDouble(r->time), s->topic, s->publisher,
                               PyLong_FromUnsignedLongLong(r->count),
                               PyLong_FromUnsignedLongLong(r->bytes)};
    PyObject *o = NULL;
    if (values[SLOT_TIME] != NULL && values[SLOT_COUNT] != NULL && values[SLOT_BYTES] != NULL)
        o = type->tp_alloc(type, 0);
    if (o == NULL) {
        Py_XDECREF(values[SLOT_TIME]);
        Py_XDECREF(values[SLOT_COUNT]);
        Py_XDECREF(values[SLOT_BYTES]);
        return NULL;
    }
    Py_INCREF(s->topic);
    Py_INCREF(s->publisher);
    for (int i = 0; i < SLOTS; i++) /* fresh object: every slot is NULL, the values move in */
        *(PyObject **)((char *)o + self->slot_offset[i]) = values[i];
    return o;
}

/* The records as Python tuples (or ready ArrivalBatch objects), in the order they happened. */
static PyObject *records_to_list(Engine *self) {
    PyObject *out = PyList_New(self->nrecs);
    if (out == NULL)
        return NULL;
    self->objects = 0;
    for (Py_ssize_t i = 0; i < self->nrecs; i++) {
        Record *r = &self->recs[i];
        const Stream *s = r->stream;
        PyObject *item = NULL;
        switch (r->kind) {
        case REC_ARRIVALS: /* the common record: built directly, not via a format string */
            if (self->batch_type != NULL && s->topic != NULL) {
                item = arrivals_object(self, r);
                self->objects += 1;
            } else {
                item = arrivals_tuple(r);
            }
            break;
        case REC_BODY:
            item = Py_BuildValue("(iIKy#d)", r->kind, r->sid, (unsigned long long)r->bytes,
                                 r->body, (Py_ssize_t)r->bytes, r->time);
            break;
        case REC_FIRST:
            item = Py_BuildValue("(iI)", r->kind, r->sid);
            break;
        default:
            item = Py_BuildValue("(iIKs)", r->kind, r->sid, (unsigned long long)r->count,
                                 r->body != NULL ? r->body : "connection closed");
        }
        if (item == NULL) {
            Py_DECREF(out);
            return NULL;
        }
        PyList_SET_ITEM(out, i, item);
    }
    return out;
}

static void clear_records(Engine *self) {
    for (Py_ssize_t i = 0; i < self->nrecs; i++)
        free(self->recs[i].body);
    self->nrecs = 0;
}

/*
 * poll(timeout, hand_over, coalesce) -> (records, woken, objects)
 *
 * Waits up to `timeout` seconds for something to read; then keeps reading until `hand_over`
 * seconds after the first record (0: after the first round that produced one), or sooner
 * when the wake-up descriptor is readable, a connection starts or ends, or a decoded topic's
 * message is complete (those need Python now). `coalesce`: at least this long between two
 * rounds, as in TcprosReader. `woken`: the wake-up descriptor is readable (Python drains it).
 * `objects`: how many records are ready ArrivalBatch objects (all of them: nothing to convert).
 */
static PyObject *Engine_poll(Engine *self, PyObject *args) {
    double timeout, hand_over, coalesce;
    if (!PyArg_ParseTuple(args, "ddd", &timeout, &hand_over, &coalesce))
        return NULL;
    int woken = 0, urgent = 0, failed = 0;
    struct epoll_event events[MAX_EVENTS];
    Py_BEGIN_ALLOW_THREADS
    double start = mono_now(), deadline = -1.0, woke = self->woke;
    for (;;) {
        double now = mono_now();
        if (coalesce > 0 && woke > 0) { /* only a busy reader waits: a quiet one at once */
            double rest = woke + coalesce - now;
            if (rest > 0) {
                sleep_seconds(rest);
                now = mono_now();
            }
        }
        double wait = deadline >= 0 ? deadline - now : start + timeout - now;
        int ms = wait <= 0 ? 0 : (int)(wait * 1000.0 + 0.999);
        int n = epoll_wait(self->epfd, events, MAX_EVENTS, ms);
        if (n < 0) {
            if (errno == EINTR)
                continue;
            failed = errno;
            break;
        }
        woke = self->woke = mono_now();
        for (int i = 0; i < n; i++) {
            Stream *s = events[i].data.ptr;
            if (s == NULL) {
                woken = 1;
                continue;
            }
            if (s->closed)
                continue;
            Py_ssize_t before = self->nrecs;
            read_stream(self, s);
            for (Py_ssize_t k = before; k < self->nrecs; k++)
                if (self->recs[k].kind != REC_ARRIVALS)
                    urgent = 1;
        }
        if (self->oom)
            break;
        if (self->nrecs && deadline < 0)
            deadline = woke + (hand_over > 0 ? hand_over : 0.0);
        if (woken || urgent || (self->nrecs && woke >= deadline))
            break;
        if (!self->nrecs && woke >= start + timeout)
            break;
    }
    Py_END_ALLOW_THREADS
    if (failed) {
        errno = failed;
        return PyErr_SetFromErrno(PyExc_OSError);
    }
    PyObject *records = records_to_list(self);
    clear_records(self);
    if (self->oom) {
        self->oom = 0;
        Py_XDECREF(records);
        return PyErr_NoMemory();
    }
    if (records == NULL)
        return NULL;
    return Py_BuildValue("(NOn)", records, woken ? Py_True : Py_False, self->objects);
}

static PyMethodDef Engine_methods[] = {
    {"add", (PyCFunction)Engine_add, METH_VARARGS,
     "add(sid, fd, max_bytes, keep_bodies[, topic, publisher]): read the non-blocking socket "
     "fd as stream sid; with the names (and a batch_type), its arrivals come as objects."},
    {"remove", (PyCFunction)Engine_remove, METH_VARARGS,
     "remove(sid) -> messages read, or -1 when unknown; the socket is not closed."},
    {"idle", (PyCFunction)Engine_idle, METH_NOARGS,
     "{sid: seconds since its last receive} of the open streams."},
    {"poll", (PyCFunction)Engine_poll, METH_VARARGS,
     "poll(timeout, hand_over, coalesce) -> (records, woken, objects)."},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject EngineType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "blackbox.sources.ros1._tcpros.Engine",
    .tp_basicsize = sizeof(Engine),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "TCPROS connections read outside the interpreter (see the module source).",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Engine_init,
    .tp_dealloc = (destructor)Engine_dealloc,
    .tp_methods = Engine_methods,
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_tcpros", "The native TCPROS receive loop.", -1, NULL, NULL, NULL,
    NULL, NULL,
};

PyMODINIT_FUNC PyInit__tcpros(void) {
    if (PyType_Ready(&EngineType) < 0)
        return NULL;
    PyObject *m = PyModule_Create(&module);
    if (m == NULL)
        return NULL;
    Py_INCREF(&EngineType);
    if (PyModule_AddObject(m, "Engine", (PyObject *)&EngineType) < 0) {
        Py_DECREF(&EngineType);
        Py_DECREF(m);
        return NULL;
    }
    PyModule_AddIntConstant(m, "ARRIVALS", REC_ARRIVALS);
    PyModule_AddIntConstant(m, "BODY", REC_BODY);
    PyModule_AddIntConstant(m, "FIRST", REC_FIRST);
    PyModule_AddIntConstant(m, "CLOSED", REC_CLOSED);
    return m;
}
