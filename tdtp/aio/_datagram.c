/*
 * tdtp.aio._datagram: batched UDP I/O for the asyncio layer (recvmmsg / sendmmsg).
 *
 * One Engine wraps a non-blocking UDP socket that Python owns (the engine only borrows its file
 * descriptor). The event loop calls Engine.drain() when the socket is readable (loop.add_reader):
 * it receives up to `batch` datagrams per recvmmsg into buffers allocated once, and hands each batch
 * to the Python callback in one call: on_batch(datagrams, addresses, timestamps_ns, traffic_class)
 * (the last two are lists, or None when not asked for). A short batch means the socket is empty,
 * so an idle socket costs one system call per wake-up. Sending: send(data, addr) is one sendto,
 * send_batch([(data, addr), ...]) one sendmmsg per `batch` datagrams.
 *
 * Coalescing (Linux, segmentation=True): send_batch sends a run of datagrams to one destination
 * with equal lengths (the last may be shorter) as one message with UDP_SEGMENT (GSO): the kernel
 * carries them through its stack as one buffer and cuts them into datagrams of that size at the
 * end (in the network card, the loopback's receiver, or in software), so up to MAX_SEGMENTS
 * datagrams cost one pass through the stack instead of one each. On the wire they are ordinary
 * datagrams. A kernel that refuses a segmented send (no checksum offload on the route, IPsec, an
 * old kernel) turns coalescing off for the engine, and the refused run is sent again datagram by
 * datagram. The receiver asks for UDP_GRO: the kernel may then hand over a run of equal datagrams
 * from one source as one buffer (with the segment size), which drain() cuts back into datagrams;
 * for that every receive slot is MAX_BUFFER bytes (allocated once, touched only as far as data
 * arrives), and a datagram longer than buffer_size is still dropped and counted.
 *
 * Nothing a peer does raises: kernel errors are counted (stats()) and reported to on_error(exc)
 * as asyncio's error_received would be; a full send buffer hands the unsent datagrams to
 * on_blocked(list) (the Python layer queues a bounded number and waits for writability).
 * Only misuse raises: a malformed address, a payload of the wrong type, a closed engine.
 *
 * Written for tdtp; Linux (recvmmsg, sendmmsg, SO_TIMESTAMPNS, IP_RECVTOS, IPV6_RECVTCLASS).
 */
#define PY_SSIZE_T_CLEAN
#define _GNU_SOURCE
#include <Python.h>
#include <structmember.h>

#include <arpa/inet.h>
#include <errno.h>
#include <net/if.h>
#include <netinet/in.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/types.h>
#include <time.h>

#define MAX_BATCH 1024
#define MIN_BUFFER 64
#define MAX_BUFFER 65536
#define MAX_TOTAL (16 * 1024 * 1024)
#define CONTROL_SPACE 128
#define DEFAULT_ROUNDS 16
#define MAX_SEGMENTS 64 /* the kernel's UDP_MAX_SEGMENTS on every kernel that has UDP_SEGMENT */
#define MAX_COALESCED 65000 /* bytes of one segmented send: below 65535 minus IP and UDP headers */
#define ADDRESS_SLOTS 256 /* per direction, a power of two: the address tables of a socket with many peers */
#ifndef SOL_UDP
#define SOL_UDP 17
#endif
#ifndef UDP_SEGMENT
#define UDP_SEGMENT 103
#endif
#ifndef UDP_GRO
#define UDP_GRO 104
#endif

typedef struct {
    unsigned long long datagrams_received;
    unsigned long long bytes_received;
    unsigned long long batches_received;
    unsigned long long recv_calls;
    unsigned long long truncated;
    unsigned long long receive_errors;
    unsigned long long port_unreachable;
    unsigned long long datagrams_sent;
    unsigned long long bytes_sent;
    unsigned long long send_calls;
    unsigned long long send_errors;
    unsigned long long too_big;
    unsigned long long no_buffer;
    unsigned long long blocked;
    unsigned long long coalesced_sends;    /* segmented messages sent (each >= 2 datagrams) */
    unsigned long long coalesced_received; /* buffers the kernel coalesced (each >= 2 datagrams) */
    unsigned long long segmentation_refused; /* segmented sends refused (coalescing then off) */
} Counters;

/* A server's socket hears from, and sends to, many peers one datagram each, interleaved: the one
 * address remembered in each direction (last_addr, last_dest) misses on nearly every datagram. Past
 * the second peer, each direction gets a table of ADDRESS_SLOTS remembered addresses (direct-mapped:
 * a collision replaces the slot), so a peer's source address is the same tuple every time (no
 * string or tuple made per datagram, and its string's hash is kept for the demultiplexer's lookup)
 * and a destination tuple is parsed once. Bounded; an engine with one peer never allocates them. */
typedef struct {
    struct sockaddr_in6 name; /* large enough for AF_INET and AF_INET6 */
    socklen_t len;
    PyObject *addr; /* the source's tuple (owned), NULL when empty */
} SourceSlot;

typedef struct {
    PyObject *addr; /* the destination object (owned: its identity is the key), NULL when empty */
    struct sockaddr_in6 name;
    socklen_t len;
} DestSlot;

typedef struct {
    PyObject_HEAD
    int fd;
    int family;
    int batch;
    int buffer_size;
    int timestamps;
    int tclass;
    int rounds;
    int paused;
    int closed;
    int segment; /* coalesce sends with UDP_SEGMENT */
    int gro;     /* the socket has UDP_GRO: receive slots are MAX_BUFFER bytes */
    int slot;    /* bytes per receive slot */
    PyObject *on_batch;
    PyObject *on_error;
    PyObject *on_blocked;
    /* receive side, allocated once */
    char *buffers;
    char *control;
    struct mmsghdr *rmsgs;
    struct iovec *riov;
    struct sockaddr_storage *rnames;
    int rdirty; /* receive headers the kernel may have written since they were last reset */
    /* the last source address seen, and its Python tuple */
    struct sockaddr_storage last_name;
    socklen_t last_len;
    PyObject *last_addr;
    SourceSlot *sources; /* ADDRESS_SLOTS, from the second source on */
    /* send side */
    struct mmsghdr *smsgs;
    struct iovec *siov;
    struct sockaddr_storage *snames;
    Py_buffer *sbufs;
    char *scontrol;     /* one UDP_SEGMENT control message per outgoing message */
    int *sfirst;        /* the first item of each outgoing message */
    int *scount;        /* how many items each outgoing message carries */
    PyObject **sdest;   /* each item's destination object (borrowed), to group runs */
    /* receive side, per message of the last recvmmsg: segment size, timestamp, traffic class */
    int *rseg;
    long long *rns;
    int *rtos;
    /* the last destination object and its socket address */
    PyObject *last_dest;
    struct sockaddr_storage last_dest_name;
    socklen_t last_dest_len;
    DestSlot *dests; /* ADDRESS_SLOTS, from the second destination on */
    Counters c;
} Engine;

static PyObject *InvalidArgumentError;
static PyObject *ArgumentTypeError;
static PyObject *ClosedError;

static int
load_errors(void)
{
    if (InvalidArgumentError != NULL)
        return 0;
    PyObject *mod = PyImport_ImportModule("tdtp.errors");
    if (mod == NULL)
        return -1;
    InvalidArgumentError = PyObject_GetAttrString(mod, "InvalidArgumentError");
    ArgumentTypeError = PyObject_GetAttrString(mod, "ArgumentTypeError");
    ClosedError = PyObject_GetAttrString(mod, "DatagramLayerClosedError");
    Py_DECREF(mod);
    if (!InvalidArgumentError || !ArgumentTypeError || !ClosedError)
        return -1;
    return 0;
}

/* ------------------------------------------------------------------------- addresses */

static PyObject *
address_to_python(const struct sockaddr_storage *ss, socklen_t len)
{
    char host[INET6_ADDRSTRLEN + 1];
    if (ss->ss_family == AF_INET) {
        const struct sockaddr_in *a = (const struct sockaddr_in *)ss;
        if (inet_ntop(AF_INET, &a->sin_addr, host, sizeof(host)) == NULL)
            return PyErr_SetFromErrno(PyExc_OSError);
        return Py_BuildValue("(si)", host, (int)ntohs(a->sin_port));
    }
    if (ss->ss_family == AF_INET6) {
        const struct sockaddr_in6 *a = (const struct sockaddr_in6 *)ss;
        if (inet_ntop(AF_INET6, &a->sin6_addr, host, sizeof(host)) == NULL)
            return PyErr_SetFromErrno(PyExc_OSError);
        return Py_BuildValue("(siII)", host, (int)ntohs(a->sin6_port),
                             (unsigned int)ntohl(a->sin6_flowinfo), (unsigned int)a->sin6_scope_id);
    }
    (void)len;
    Py_RETURN_NONE;
}

/* An address table's slot for a socket address (FNV-1a over its bytes). */
static unsigned int
name_slot(const struct sockaddr_storage *ss, socklen_t len)
{
    const unsigned char *p = (const unsigned char *)ss;
    uint32_t h = 2166136261u;
    for (socklen_t i = 0; i < len; i++) {
        h ^= p[i];
        h *= 16777619u;
    }
    return (h ^ (h >> 16)) & (ADDRESS_SLOTS - 1);
}

/* An address table's slot for a destination object (its identity). */
static unsigned int
object_slot(PyObject *addr)
{
    uint64_t h = (uint64_t)(uintptr_t)addr * 0x9E3779B97F4A7C15ull;
    return (unsigned int)(h >> 32) & (ADDRESS_SLOTS - 1);
}

/* The Python tuple for a source address: the same object as last time when the address is (and,
 * with many sources, as the last time it was seen: SourceSlot). */
static PyObject *
source_address(Engine *self, const struct sockaddr_storage *ss, socklen_t len)
{
    if (self->last_addr != NULL && len == self->last_len && memcmp(ss, &self->last_name, len) == 0) {
        Py_INCREF(self->last_addr);
        return self->last_addr;
    }
    SourceSlot *slot = NULL;
    if (self->last_addr != NULL && len <= (socklen_t)sizeof(struct sockaddr_in6)) {
        if (self->sources == NULL)
            self->sources = PyMem_Calloc(ADDRESS_SLOTS, sizeof(SourceSlot)); /* NULL: no table */
        if (self->sources != NULL) {
            slot = &self->sources[name_slot(ss, len)];
            if (slot->addr != NULL && slot->len == len && memcmp(ss, &slot->name, len) == 0) {
                Py_XSETREF(self->last_addr, Py_NewRef(slot->addr));
                memcpy(&self->last_name, ss, len);
                self->last_len = len;
                return Py_NewRef(slot->addr);
            }
        }
    }
    PyObject *addr = address_to_python(ss, len);
    if (addr == NULL)
        return NULL;
    if (slot != NULL) {
        Py_XSETREF(slot->addr, Py_NewRef(addr));
        memcpy(&slot->name, ss, len);
        slot->len = len;
    }
    Py_XSETREF(self->last_addr, Py_NewRef(addr));
    memcpy(&self->last_name, ss, len);
    self->last_len = len;
    return addr;
}

/* (host, port) or (host, port, flowinfo, scope_id) with a numeric host -> a socket address of the
 * engine's family (IPv4 destinations of an IPv6 socket are mapped). 0, or -1 with an exception. */
static int
address_from_python(Engine *self, PyObject *addr, struct sockaddr_storage *out, socklen_t *outlen)
{
    if (!PyTuple_Check(addr) || PyTuple_GET_SIZE(addr) < 2 || PyTuple_GET_SIZE(addr) > 4) {
        PyErr_Format(ArgumentTypeError,
                     "an address must be a (host, port) tuple with a numeric host, got %R", addr);
        return -1;
    }
    PyObject *host_obj = PyTuple_GET_ITEM(addr, 0);
    PyObject *port_obj = PyTuple_GET_ITEM(addr, 1);
    if (!PyUnicode_Check(host_obj) || !PyLong_Check(port_obj)) {
        PyErr_Format(ArgumentTypeError,
                     "an address must be a (host: str, port: int) tuple, got %R", addr);
        return -1;
    }
    long port = PyLong_AsLong(port_obj);
    if (port < 0 || port > 65535) {
        if (!PyErr_Occurred())
            PyErr_Format(InvalidArgumentError, "port must be in 0..65535, got %ld", port);
        return -1;
    }
    const char *host = PyUnicode_AsUTF8(host_obj);
    if (host == NULL)
        return -1;
    char buf[INET6_ADDRSTRLEN + IF_NAMESIZE + 2];
    unsigned int scope = 0;
    const char *pct = strchr(host, '%');
    if (pct != NULL) {
        size_t n = (size_t)(pct - host);
        if (n >= sizeof(buf))
            goto bad;
        memcpy(buf, host, n);
        buf[n] = '\0';
        scope = if_nametoindex(pct + 1);
        if (scope == 0) {
            char *end;
            unsigned long v = strtoul(pct + 1, &end, 10);
            if (*end != '\0')
                goto bad;
            scope = (unsigned int)v;
        }
        host = buf;
    }
    memset(out, 0, sizeof(*out));
    struct in_addr v4;
    struct in6_addr v6;
    if (inet_pton(AF_INET, host, &v4) == 1) {
        if (self->family == AF_INET6) {
            struct sockaddr_in6 *a = (struct sockaddr_in6 *)out;
            a->sin6_family = AF_INET6;
            a->sin6_port = htons((uint16_t)port);
            a->sin6_addr.s6_addr[10] = 0xff;
            a->sin6_addr.s6_addr[11] = 0xff;
            memcpy(&a->sin6_addr.s6_addr[12], &v4, 4);
            *outlen = sizeof(*a);
        } else {
            struct sockaddr_in *a = (struct sockaddr_in *)out;
            a->sin_family = AF_INET;
            a->sin_port = htons((uint16_t)port);
            a->sin_addr = v4;
            *outlen = sizeof(*a);
        }
        return 0;
    }
    if (inet_pton(AF_INET6, host, &v6) == 1) {
        if (self->family != AF_INET6) {
            PyErr_Format(InvalidArgumentError,
                         "an IPv6 destination %R for an IPv4 socket", addr);
            return -1;
        }
        struct sockaddr_in6 *a = (struct sockaddr_in6 *)out;
        a->sin6_family = AF_INET6;
        a->sin6_port = htons((uint16_t)port);
        a->sin6_addr = v6;
        if (PyTuple_GET_SIZE(addr) >= 3) {
            unsigned long flow = PyLong_AsUnsignedLong(PyTuple_GET_ITEM(addr, 2));
            if (PyErr_Occurred())
                return -1;
            a->sin6_flowinfo = htonl((uint32_t)flow);
        }
        if (PyTuple_GET_SIZE(addr) == 4) {
            unsigned long sc = PyLong_AsUnsignedLong(PyTuple_GET_ITEM(addr, 3));
            if (PyErr_Occurred())
                return -1;
            if (sc)
                scope = (unsigned int)sc;
        }
        a->sin6_scope_id = scope;
        *outlen = sizeof(*a);
        return 0;
    }
bad:
    PyErr_Format(InvalidArgumentError,
                 "the host of %R is not a numeric IPv4 or IPv6 address (resolve names first)", addr);
    return -1;
}

static int
destination(Engine *self, PyObject *addr, struct sockaddr_storage *out, socklen_t *outlen)
{
    if (addr == self->last_dest && addr != NULL) {
        memcpy(out, &self->last_dest_name, self->last_dest_len);
        *outlen = self->last_dest_len;
        return 0;
    }
    DestSlot *slot = NULL;
    if (self->last_dest != NULL && addr != NULL) {
        if (self->dests == NULL)
            self->dests = PyMem_Calloc(ADDRESS_SLOTS, sizeof(DestSlot)); /* NULL: no table */
        if (self->dests != NULL) {
            slot = &self->dests[object_slot(addr)];
            if (slot->addr == addr) {
                memcpy(out, &slot->name, slot->len);
                *outlen = slot->len;
                Py_XSETREF(self->last_dest, Py_NewRef(addr));
                memcpy(&self->last_dest_name, out, *outlen);
                self->last_dest_len = *outlen;
                return 0;
            }
        }
    }
    if (address_from_python(self, addr, out, outlen) < 0)
        return -1;
    if (slot != NULL && *outlen <= (socklen_t)sizeof(struct sockaddr_in6)) {
        Py_XSETREF(slot->addr, Py_NewRef(addr));
        memcpy(&slot->name, out, *outlen);
        slot->len = *outlen;
    }
    Py_XSETREF(self->last_dest, Py_NewRef(addr));
    memcpy(&self->last_dest_name, out, *outlen);
    self->last_dest_len = *outlen;
    return 0;
}

/* ------------------------------------------------------------------------- errors */

/* Count a kernel error and report it to on_error (as asyncio's error_received). -1 if the callback
 * raised (its exception is set). */
static int
report_error(Engine *self, int err, int sending)
{
    if (err == ECONNREFUSED)
        self->c.port_unreachable++;
    if (sending) {
        self->c.send_errors++;
        if (err == EMSGSIZE)
            self->c.too_big++;
        else if (err == ENOBUFS || err == ENOMEM)
            self->c.no_buffer++;
    } else {
        self->c.receive_errors++;
    }
    if (self->on_error == Py_None)
        return 0;
    PyObject *args = Py_BuildValue("(is)", err, strerror(err));
    if (args == NULL)
        return -1;
    PyObject *exc = PyObject_Call(PyExc_OSError, args, NULL); /* picks the subclass by errno */
    Py_DECREF(args);
    if (exc == NULL)
        return -1;
    PyObject *r = PyObject_CallOneArg(self->on_error, exc);
    Py_DECREF(exc);
    if (r == NULL)
        return -1;
    Py_DECREF(r);
    return 0;
}

static int
check_open(Engine *self)
{
    if (self->closed) {
        PyErr_SetString(ClosedError, "the datagram layer is closed");
        return -1;
    }
    return 0;
}

/* ------------------------------------------------------------------------- receiving */

/* What the kernel said of message i: its timestamp, traffic class and, for a coalesced buffer,
 * the segment size (0 when it is one datagram). */
static void
read_control(Engine *self, int i)
{
    struct msghdr *h = &self->rmsgs[i].msg_hdr;
    long long ns = -1;
    int tos = -1, seg = 0;
    if (h->msg_controllen > 0) {
        for (struct cmsghdr *cm = CMSG_FIRSTHDR(h); cm != NULL; cm = CMSG_NXTHDR(h, cm)) {
            if (cm->cmsg_level == SOL_SOCKET && cm->cmsg_type == SO_TIMESTAMPNS) {
                struct timespec ts;
                memcpy(&ts, CMSG_DATA(cm), sizeof(ts));
                ns = (long long)ts.tv_sec * 1000000000LL + ts.tv_nsec;
            } else if (cm->cmsg_level == IPPROTO_IP && cm->cmsg_type == IP_TOS) {
                tos = *(unsigned char *)CMSG_DATA(cm);
            } else if (cm->cmsg_level == IPPROTO_IPV6 && cm->cmsg_type == IPV6_TCLASS) {
                int v;
                memcpy(&v, CMSG_DATA(cm), sizeof(v));
                tos = v & 0xff;
            } else if (cm->cmsg_level == SOL_UDP && cm->cmsg_type == UDP_GRO) {
                int v = 0;
                if (cm->cmsg_len >= CMSG_LEN(sizeof(int)))
                    memcpy(&v, CMSG_DATA(cm), sizeof(int));
                else if (cm->cmsg_len >= CMSG_LEN(sizeof(uint16_t))) {
                    uint16_t v16;
                    memcpy(&v16, CMSG_DATA(cm), sizeof(v16));
                    v = v16;
                }
                seg = v;
            }
        }
    }
    self->rns[i] = ns;
    self->rtos[i] = tos;
    self->rseg[i] = seg;
}

static PyObject *
deliver(Engine *self, int n)
{
    /* first pass: how many datagrams the n messages hold (a coalesced buffer holds several) */
    Py_ssize_t total = 0;
    for (int i = 0; i < n; i++) {
        read_control(self, i);
        unsigned int len = self->rmsgs[i].msg_len;
        int seg = self->rseg[i];
        if (self->rmsgs[i].msg_hdr.msg_flags & MSG_TRUNC)
            continue;
        if (seg > 0 && (unsigned int)seg < len) {
            total += (len + (unsigned int)seg - 1) / (unsigned int)seg;
            self->c.coalesced_received++;
        } else {
            self->rseg[i] = 0;
            total += 1;
        }
    }
    PyObject *datas = PyList_New(total), *addrs = PyList_New(total);
    PyObject *stamps = NULL, *classes = NULL;
    if (datas == NULL || addrs == NULL)
        goto fail;
    if (self->timestamps && (stamps = PyList_New(total)) == NULL)
        goto fail;
    if (self->tclass && (classes = PyList_New(total)) == NULL)
        goto fail;
    Py_ssize_t kept = 0;
    for (int i = 0; i < n; i++) {
        struct msghdr *h = &self->rmsgs[i].msg_hdr;
        unsigned int len = self->rmsgs[i].msg_len;
        if (h->msg_flags & MSG_TRUNC) {
            self->c.truncated++; /* larger than the slot: lost and counted */
            continue;
        }
        const char *base = (const char *)self->riov[i].iov_base;
        /* a coalesced buffer holds datagrams of rseg bytes (the last may be shorter) */
        unsigned int seg = self->rseg[i] > 0 ? (unsigned int)self->rseg[i] : len;
        unsigned int pieces = self->rseg[i] > 0 ? (len + seg - 1) / seg : 1;
        PyObject *addr = NULL;
        for (unsigned int k = 0; k < pieces; k++) {
            unsigned int off = k * seg;
            unsigned int piece = len - off < seg ? len - off : seg;
            if (piece > (unsigned int)self->buffer_size) {
                self->c.truncated++; /* longer than buffer_size: lost and counted */
                continue;
            }
            PyObject *data = PyBytes_FromStringAndSize(base + off, piece);
            if (data == NULL)
                goto fail;
            if (addr == NULL) {
                addr = source_address(self, &self->rnames[i], h->msg_namelen);
                if (addr == NULL) {
                    Py_DECREF(data);
                    goto fail;
                }
            } else {
                Py_INCREF(addr);
            }
            PyList_SET_ITEM(datas, kept, data);
            PyList_SET_ITEM(addrs, kept, addr);
            if (stamps != NULL) {
                PyObject *o = PyLong_FromLongLong(self->rns[i]);
                if (o == NULL)
                    goto fail;
                PyList_SET_ITEM(stamps, kept, o);
            }
            if (classes != NULL)
                PyList_SET_ITEM(classes, kept, PyLong_FromLong(self->rtos[i])); /* small: cached */
            kept++;
            self->c.datagrams_received++;
            self->c.bytes_received += piece;
        }
    }
    if (kept < total) { /* dropped ones left holes at the end: shrink the lists */
        if (PyList_SetSlice(datas, kept, total, NULL) < 0 ||
            PyList_SetSlice(addrs, kept, total, NULL) < 0)
            goto fail;
        if (stamps && PyList_SetSlice(stamps, kept, total, NULL) < 0)
            goto fail;
        if (classes && PyList_SetSlice(classes, kept, total, NULL) < 0)
            goto fail;
    }
    if (kept == 0) {
        Py_DECREF(datas);
        Py_DECREF(addrs);
        Py_XDECREF(stamps);
        Py_XDECREF(classes);
        Py_RETURN_NONE;
    }
    self->c.batches_received++;
    PyObject *args[4] = {datas, addrs, stamps ? stamps : Py_None, classes ? classes : Py_None};
    PyObject *callback = Py_NewRef(self->on_batch); /* set_on_batch may replace it meanwhile */
    PyObject *r = PyObject_Vectorcall(callback, args, 4, NULL);
    Py_DECREF(callback);
    Py_DECREF(datas);
    Py_DECREF(addrs);
    Py_XDECREF(stamps);
    Py_XDECREF(classes);
    return r;
fail:
    /* a list's unset slots are NULL, which list deallocation skips */
    Py_XDECREF(datas);
    Py_XDECREF(addrs);
    Py_XDECREF(stamps);
    Py_XDECREF(classes);
    return NULL;
}

/* Every receive header, once: where each one's name, buffer and control space are. */
static void
setup_receive(Engine *self)
{
    int want_control = self->timestamps || self->tclass || self->gro;
    for (int i = 0; i < self->batch; i++) {
        struct msghdr *h = &self->rmsgs[i].msg_hdr;
        h->msg_name = &self->rnames[i];
        h->msg_iov = &self->riov[i];
        h->msg_iovlen = 1;
        h->msg_control = want_control ? self->control + (size_t)i * CONTROL_SPACE : NULL;
    }
    self->rdirty = self->batch;
}

/* Before a recvmmsg: the lengths and flags the kernel wrote into the headers it filled last time
 * (it writes nothing else, and only into the headers of the datagrams it returned), so that a
 * wake-up for one datagram resets one header, not the whole batch's (64 of them, 4 KiB, on the way
 * from the wake-up to the answer). */
static void
reset_receive(Engine *self)
{
    int want_control = self->timestamps || self->tclass || self->gro;
    for (int i = 0; i < self->rdirty; i++) {
        struct msghdr *h = &self->rmsgs[i].msg_hdr;
        h->msg_namelen = sizeof(struct sockaddr_storage);
        h->msg_controllen = want_control ? CONTROL_SPACE : 0;
        h->msg_flags = 0;
    }
    self->rdirty = 0;
}

/* The reader: drain the socket, one callback per recvmmsg batch. Returns how many datagrams
 * were delivered. Stops at a short batch (the socket is empty), EAGAIN, or after `rounds` full
 * batches (so that other readers on the loop get their turn; the loop calls again); with receive
 * coalescing, also once rounds x batch datagrams were delivered (a full batch of coalesced buffers
 * holds up to MAX_SEGMENTS times as many, so a turn is at most one such batch). */
static PyObject *
Engine_drain(Engine *self, PyObject *Py_UNUSED(ignored))
{
    if (self->closed)
        return PyLong_FromLong(0);
    unsigned long long before = self->c.datagrams_received;
    for (int round = 0; round < self->rounds; round++) {
        reset_receive(self);
        /* non-blocking: no need to release the GIL */
        int n = recvmmsg(self->fd, self->rmsgs, (unsigned int)self->batch, MSG_DONTWAIT, NULL);
        self->c.recv_calls++;
        self->rdirty = n > 0 ? n : 0;
        if (n < 0) {
            int err = errno;
            if (err != EAGAIN && err != EWOULDBLOCK)
                self->rdirty = self->batch; /* an error after some datagrams: all may be written */
            if (err == EINTR) {
                if (PyErr_CheckSignals() < 0)
                    return NULL;
                continue;
            }
            if (err == EAGAIN || err == EWOULDBLOCK)
                break;
            if (report_error(self, err, 0) < 0)
                return NULL;
            if (err == ECONNREFUSED)
                continue; /* the pending ICMP error is cleared by reporting it; read on */
            break;
        }
        if (n == 0)
            break;
        PyObject *r = deliver(self, n);
        if (r == NULL)
            return NULL;
        Py_DECREF(r);
        if (n < self->batch || self->closed)
            break;
        /* coalesced buffers hold many datagrams each: the turn ends after rounds x batch of them */
        if (self->gro && self->c.datagrams_received - before >= (unsigned long long)self->rounds * (unsigned long long)self->batch)
            break;
    }
    return PyLong_FromUnsignedLongLong(self->c.datagrams_received - before);
}

/* ------------------------------------------------------------------------- sending */

static int
hand_back(Engine *self, PyObject *items, Py_ssize_t start, Py_ssize_t stop)
{
    Py_ssize_t n = stop - start;
    if (n <= 0)
        return 0;
    self->c.blocked++;
    if (self->on_blocked == Py_None)
        return 0;
    PyObject *rest = PyList_GetSlice(items, start, stop);
    if (rest == NULL)
        return -1;
    PyObject *r = PyObject_CallOneArg(self->on_blocked, rest);
    Py_DECREF(rest);
    if (r == NULL)
        return -1;
    Py_DECREF(r);
    return 0;
}

static int
get_payload(PyObject *data, Py_buffer *view)
{
    if (PyObject_GetBuffer(data, view, PyBUF_SIMPLE) < 0) {
        PyErr_Clear();
        PyErr_Format(ArgumentTypeError, "a datagram must be bytes-like, got %.100s",
                     Py_TYPE(data)->tp_name);
        return -1;
    }
    return 0;
}

/* send(data, addr=None) -> True if the kernel took it. One sendto. */
static PyObject *
Engine_send(Engine *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs < 1 || nargs > 2) {
        PyErr_SetString(PyExc_TypeError, "send(data, addr=None)");
        return NULL;
    }
    if (check_open(self) < 0)
        return NULL;
    PyObject *addr = nargs == 2 ? args[1] : Py_None;
    struct sockaddr_storage ss;
    socklen_t sl = 0;
    if (addr != Py_None && destination(self, addr, &ss, &sl) < 0)
        return NULL;
    if (self->paused) {
        PyObject *item = PyTuple_Pack(2, args[0], addr);
        PyObject *list = item ? PyList_New(1) : NULL;
        if (list == NULL) {
            Py_XDECREF(item);
            return NULL;
        }
        PyList_SET_ITEM(list, 0, item);
        int rc = hand_back(self, list, 0, 1);
        Py_DECREF(list);
        if (rc < 0)
            return NULL;
        Py_RETURN_FALSE;
    }
    Py_buffer view;
    const char *p;
    Py_ssize_t len;
    int have_view = 0;
    if (PyBytes_CheckExact(args[0])) {
        p = PyBytes_AS_STRING(args[0]);
        len = PyBytes_GET_SIZE(args[0]);
    } else {
        if (get_payload(args[0], &view) < 0)
            return NULL;
        have_view = 1;
        p = view.buf;
        len = view.len;
    }
    ssize_t r;
    int err = 0;
    for (;;) {
        r = sendto(self->fd, p, (size_t)len, MSG_DONTWAIT, addr == Py_None ? NULL : (struct sockaddr *)&ss,
                   sl);
        self->c.send_calls++;
        if (r >= 0)
            break;
        err = errno;
        if (err != EINTR)
            break;
    }
    if (r >= 0) {
        if (have_view)
            PyBuffer_Release(&view);
        self->c.datagrams_sent++;
        self->c.bytes_sent += (unsigned long long)len;
        Py_RETURN_TRUE;
    }
    if (err == EAGAIN || err == EWOULDBLOCK) {
        PyObject *item = PyTuple_Pack(2, args[0], addr);
        if (have_view)
            PyBuffer_Release(&view);
        PyObject *list = item ? PyList_New(1) : NULL;
        if (list == NULL) {
            Py_XDECREF(item);
            return NULL;
        }
        PyList_SET_ITEM(list, 0, item);
        int rc = hand_back(self, list, 0, 1);
        Py_DECREF(list);
        if (rc < 0)
            return NULL;
        Py_RETURN_FALSE;
    }
    if (have_view)
        PyBuffer_Release(&view);
    if (report_error(self, err, 1) < 0)
        return NULL;
    Py_RETURN_FALSE;
}

/* Group items [0, count) of the chunk into outgoing messages: with segmentation, a run to one
 * destination (the same object, or the same socket address) whose datagrams have one length,
 * the last possibly shorter, becomes one message with a UDP_SEGMENT control message. Returns the
 * number of messages. */
static int
build_messages(Engine *self, Py_ssize_t count)
{
    int m = 0;
    Py_ssize_t k = 0;
    while (k < count) {
        Py_ssize_t first = k;
        size_t size = self->siov[k].iov_len;
        size_t bytes = size;
        k++;
        if (self->segment && size > 0) {
            struct msghdr *fh = &self->smsgs[first].msg_hdr;
            while (k < count && k - first < MAX_SEGMENTS) {
                size_t next = self->siov[k].iov_len;
                if (next == 0 || next > size || bytes + next > MAX_COALESCED)
                    break;
                struct msghdr *kh = &self->smsgs[k].msg_hdr;
                if (self->sdest[k] != self->sdest[first] &&
                    (kh->msg_namelen != fh->msg_namelen ||
                     memcmp(kh->msg_name, fh->msg_name, kh->msg_namelen) != 0))
                    break;
                bytes += next;
                k++;
                if (next < size)
                    break; /* a shorter datagram ends the run */
            }
        }
        /* the message's header: the first item's name; its iovecs are the run's, in place */
        struct mmsghdr *msg = &self->smsgs[m];
        if (m != first)
            msg->msg_hdr = self->smsgs[first].msg_hdr; /* m <= first: that header is not needed again */
        msg->msg_hdr.msg_iov = &self->siov[first];
        msg->msg_hdr.msg_iovlen = (size_t)(k - first);
        msg->msg_hdr.msg_control = NULL;
        msg->msg_hdr.msg_controllen = 0;
        if (k - first > 1) {
            char *buf = self->scontrol + (size_t)m * CMSG_SPACE(sizeof(uint16_t));
            msg->msg_hdr.msg_control = buf;
            msg->msg_hdr.msg_controllen = CMSG_SPACE(sizeof(uint16_t));
            struct cmsghdr *cm = CMSG_FIRSTHDR(&msg->msg_hdr);
            cm->cmsg_level = SOL_UDP;
            cm->cmsg_type = UDP_SEGMENT;
            cm->cmsg_len = CMSG_LEN(sizeof(uint16_t));
            uint16_t gso = (uint16_t)size;
            memcpy(CMSG_DATA(cm), &gso, sizeof(gso));
        }
        self->sfirst[m] = (int)first;
        self->scount[m] = (int)(k - first);
        m++;
    }
    return m;
}

/* A kernel refusing a segmented send says so with one of these: the route cannot checksum in
 * hardware or is IPsec (EIO), the segment does not fit the route's MTU or the socket opted out of
 * checksums (EINVAL), the kernel has no UDP_SEGMENT (ENOPROTOOPT, EOPNOTSUPP). */
static int
segmentation_refused(int err)
{
    return err == EIO || err == EINVAL || err == ENOPROTOOPT || err == EOPNOTSUPP;
}

/* send_batch(items) -> how many the kernel took. items: a list of (data, addr or None). */
static PyObject *
Engine_send_batch(Engine *self, PyObject *items)
{
    if (check_open(self) < 0)
        return NULL;
    if (!PyList_Check(items)) {
        PyErr_Format(ArgumentTypeError, "send_batch takes a list of (data, addr) pairs, got %.100s",
                     Py_TYPE(items)->tp_name);
        return NULL;
    }
    Py_ssize_t total = PyList_GET_SIZE(items);
    if (self->paused) {
        if (hand_back(self, items, 0, total) < 0)
            return NULL;
        return PyLong_FromLong(0);
    }
    long sent = 0;
    Py_ssize_t start = 0;
    while (start < total) {
        Py_ssize_t chunk = total - start;
        if (chunk > self->batch)
            chunk = self->batch;
        /* fill the chunk's headers, holding each payload's buffer */
        Py_ssize_t filled = 0;
        for (; filled < chunk; filled++) {
            PyObject *item = PyList_GET_ITEM(items, start + filled);
            if (!PyTuple_Check(item) || PyTuple_GET_SIZE(item) != 2) {
                PyErr_Format(ArgumentTypeError, "send_batch items are (data, addr) pairs, got %R",
                             item);
                goto fail;
            }
            PyObject *addr = PyTuple_GET_ITEM(item, 1);
            struct msghdr *h = &self->smsgs[filled].msg_hdr;
            memset(h, 0, sizeof(*h));
            self->sdest[filled] = addr;
            if (addr != Py_None) {
                socklen_t sl;
                if (destination(self, addr, &self->snames[filled], &sl) < 0)
                    goto fail;
                h->msg_name = &self->snames[filled];
                h->msg_namelen = sl;
            }
            if (get_payload(PyTuple_GET_ITEM(item, 0), &self->sbufs[filled]) < 0)
                goto fail;
            self->siov[filled].iov_base = self->sbufs[filled].buf;
            self->siov[filled].iov_len = (size_t)self->sbufs[filled].len;
        }
        int messages = build_messages(self, chunk);
        /* send the chunk's messages; an error belongs to the first message not sent */
        int done = 0;
        int blocked = 0, resend = 0;
        while (done < messages) {
            int r = sendmmsg(self->fd, self->smsgs + done, (unsigned int)(messages - done),
                             MSG_DONTWAIT);
            self->c.send_calls++;
            if (r > 0) {
                for (int m = done; m < done + r; m++) {
                    int first = self->sfirst[m], count = self->scount[m];
                    for (int k = first; k < first + count; k++)
                        self->c.bytes_sent += self->siov[k].iov_len;
                    self->c.datagrams_sent += (unsigned long long)count;
                    if (count > 1)
                        self->c.coalesced_sends++;
                    sent += count;
                }
                done += r;
                continue;
            }
            int err = errno;
            if (err == EINTR)
                continue;
            if (err == EAGAIN || err == EWOULDBLOCK) {
                blocked = 1;
                break;
            }
            if (self->scount[done] > 1 && segmentation_refused(err)) {
                /* this route or kernel does not segment: send one by one from here on */
                self->segment = 0;
                self->c.segmentation_refused++;
                resend = 1;
                break;
            }
            if (report_error(self, err, 1) < 0) {
                for (Py_ssize_t k = 0; k < chunk; k++)
                    PyBuffer_Release(&self->sbufs[k]);
                return NULL;
            }
            done++; /* that message's datagrams are lost; go on with the next */
        }
        Py_ssize_t next = done < messages ? self->sfirst[done] : chunk;
        for (Py_ssize_t k = 0; k < chunk; k++)
            PyBuffer_Release(&self->sbufs[k]);
        if (blocked) {
            if (hand_back(self, items, start + next, total) < 0)
                return NULL;
            break;
        }
        start += resend ? next : chunk; /* a refused run goes again, unsegmented */
        continue;
    fail:
        for (Py_ssize_t k = 0; k < filled; k++)
            PyBuffer_Release(&self->sbufs[k]);
        return NULL;
    }
    return PyLong_FromLong(sent);
}

/* ------------------------------------------------------------------------- the rest */

static PyObject *
Engine_stats(Engine *self, PyObject *Py_UNUSED(ignored))
{
    Counters *c = &self->c;
    return Py_BuildValue(
        "{sKsKsKsKsKsKsKsKsKsKsKsKsKsKsKsKsKsisi}", "datagrams_received", c->datagrams_received,
        "bytes_received", c->bytes_received, "batches_received", c->batches_received, "recv_calls",
        c->recv_calls, "truncated", c->truncated, "receive_errors", c->receive_errors,
        "port_unreachable", c->port_unreachable, "datagrams_sent", c->datagrams_sent, "bytes_sent",
        c->bytes_sent, "send_calls", c->send_calls, "send_errors", c->send_errors, "too_big",
        c->too_big, "no_buffer", c->no_buffer, "blocked", c->blocked, "coalesced_sends",
        c->coalesced_sends, "coalesced_received", c->coalesced_received, "segmentation_refused",
        c->segmentation_refused, "segmenting", self->segment, "receive_coalescing", self->gro);
}

static PyObject *
Engine_set_paused(Engine *self, PyObject *arg)
{
    int v = PyObject_IsTrue(arg);
    if (v < 0)
        return NULL;
    self->paused = v;
    Py_RETURN_NONE;
}

static PyObject *
Engine_set_on_batch(Engine *self, PyObject *callback)
{
    if (!PyCallable_Check(callback)) {
        PyErr_SetString(ArgumentTypeError, "on_batch must be callable");
        return NULL;
    }
    Py_XSETREF(self->on_batch, Py_NewRef(callback));
    Py_RETURN_NONE;
}

static PyObject *
Engine_close(Engine *self, PyObject *Py_UNUSED(ignored))
{
    self->closed = 1;
    self->fd = -1;
    Py_RETURN_NONE;
}

static void
free_buffers(Engine *self)
{
    PyMem_Free(self->buffers);
    PyMem_Free(self->control);
    PyMem_Free(self->rmsgs);
    PyMem_Free(self->riov);
    PyMem_Free(self->rnames);
    PyMem_Free(self->smsgs);
    PyMem_Free(self->siov);
    PyMem_Free(self->snames);
    PyMem_Free(self->sbufs);
    PyMem_Free(self->scontrol);
    PyMem_Free(self->sfirst);
    PyMem_Free(self->scount);
    PyMem_Free(self->sdest);
    PyMem_Free(self->rseg);
    PyMem_Free(self->rns);
    PyMem_Free(self->rtos);
    self->scontrol = NULL;
    self->sfirst = self->scount = self->rseg = self->rtos = NULL;
    self->sdest = NULL;
    self->rns = NULL;
    self->buffers = self->control = NULL;
    self->rmsgs = self->smsgs = NULL;
    self->riov = self->siov = NULL;
    self->rnames = self->snames = NULL;
    self->sbufs = NULL;
}

static int
Engine_traverse(Engine *self, visitproc visit, void *arg)
{
    Py_VISIT(self->on_batch);
    Py_VISIT(self->on_error);
    Py_VISIT(self->on_blocked);
    Py_VISIT(self->last_addr);
    Py_VISIT(self->last_dest);
    for (int i = 0; self->sources != NULL && i < ADDRESS_SLOTS; i++)
        Py_VISIT(self->sources[i].addr);
    for (int i = 0; self->dests != NULL && i < ADDRESS_SLOTS; i++)
        Py_VISIT(self->dests[i].addr);
    return 0;
}

static int
Engine_clear(Engine *self)
{
    Py_CLEAR(self->on_batch);
    Py_CLEAR(self->on_error);
    Py_CLEAR(self->on_blocked);
    Py_CLEAR(self->last_addr);
    Py_CLEAR(self->last_dest);
    for (int i = 0; self->sources != NULL && i < ADDRESS_SLOTS; i++)
        Py_CLEAR(self->sources[i].addr);
    for (int i = 0; self->dests != NULL && i < ADDRESS_SLOTS; i++)
        Py_CLEAR(self->dests[i].addr);
    return 0;
}

static void
Engine_dealloc(Engine *self)
{
    PyObject_GC_UnTrack(self);
    Engine_clear(self);
    PyMem_Free(self->sources);
    PyMem_Free(self->dests);
    self->sources = NULL;
    self->dests = NULL;
    free_buffers(self);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int
Engine_init(Engine *self, PyObject *args, PyObject *kwds)
{
    static char *kwlist[] = {"fd", "family", "batch", "buffer_size", "on_batch", "on_error",
                             "on_blocked", "timestamps", "traffic_class", "coalesce", NULL};
    int fd, family, batch, buffer_size, timestamps = 0, tclass = 0, coalesce = 0;
    PyObject *on_batch, *on_error = Py_None, *on_blocked = Py_None;
    if (load_errors() < 0)
        return -1;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "iiiiO|$OOppp", kwlist, &fd, &family, &batch,
                                     &buffer_size, &on_batch, &on_error, &on_blocked, &timestamps,
                                     &tclass, &coalesce))
        return -1;
    if (fd < 0) {
        PyErr_Format(InvalidArgumentError, "fd must be an open file descriptor, got %d", fd);
        return -1;
    }
    if (family != AF_INET && family != AF_INET6) {
        PyErr_Format(InvalidArgumentError, "family must be AF_INET or AF_INET6, got %d", family);
        return -1;
    }
    if (batch < 1 || batch > MAX_BATCH) {
        PyErr_Format(InvalidArgumentError, "batch must be in 1..%d, got %d", MAX_BATCH, batch);
        return -1;
    }
    if (buffer_size < MIN_BUFFER || buffer_size > MAX_BUFFER) {
        PyErr_Format(InvalidArgumentError, "buffer_size must be in %d..%d, got %d", MIN_BUFFER,
                     MAX_BUFFER, buffer_size);
        return -1;
    }
    if ((long long)batch * buffer_size > MAX_TOTAL) {
        PyErr_Format(InvalidArgumentError,
                     "batch x buffer_size must be at most %d bytes, got %d x %d", MAX_TOTAL, batch,
                     buffer_size);
        return -1;
    }
    if (!PyCallable_Check(on_batch) || (on_error != Py_None && !PyCallable_Check(on_error)) ||
        (on_blocked != Py_None && !PyCallable_Check(on_blocked))) {
        PyErr_SetString(ArgumentTypeError, "on_batch, on_error and on_blocked must be callable");
        return -1;
    }
    free_buffers(self);
    size_t b = (size_t)batch;
    /* Receive coalescing needs slots that hold a whole coalesced buffer; where the batch cannot
     * have them within MAX_TOTAL, or the kernel has no UDP_GRO, the socket receives one by one. */
    int gro = 0;
    if (coalesce && (long long)batch * MAX_BUFFER <= MAX_TOTAL) {
        int on = 1;
        gro = setsockopt(fd, SOL_UDP, UDP_GRO, &on, sizeof(on)) == 0;
    }
    int slot = gro ? MAX_BUFFER : buffer_size;
    self->buffers = PyMem_Malloc(b * (size_t)slot);
    self->control = PyMem_Calloc(b, CONTROL_SPACE);
    self->rmsgs = PyMem_Calloc(b, sizeof(struct mmsghdr));
    self->riov = PyMem_Calloc(b, sizeof(struct iovec));
    self->rnames = PyMem_Calloc(b, sizeof(struct sockaddr_storage));
    self->smsgs = PyMem_Calloc(b, sizeof(struct mmsghdr));
    self->siov = PyMem_Calloc(b, sizeof(struct iovec));
    self->snames = PyMem_Calloc(b, sizeof(struct sockaddr_storage));
    self->sbufs = PyMem_Calloc(b, sizeof(Py_buffer));
    self->scontrol = PyMem_Calloc(b, CMSG_SPACE(sizeof(uint16_t)));
    self->sfirst = PyMem_Calloc(b, sizeof(int));
    self->scount = PyMem_Calloc(b, sizeof(int));
    self->sdest = PyMem_Calloc(b, sizeof(PyObject *));
    self->rseg = PyMem_Calloc(b, sizeof(int));
    self->rns = PyMem_Calloc(b, sizeof(long long));
    self->rtos = PyMem_Calloc(b, sizeof(int));
    if (!self->buffers || !self->control || !self->rmsgs || !self->riov || !self->rnames ||
        !self->smsgs || !self->siov || !self->snames || !self->sbufs || !self->scontrol ||
        !self->sfirst || !self->scount || !self->sdest || !self->rseg || !self->rns ||
        !self->rtos) {
        free_buffers(self);
        PyErr_NoMemory();
        return -1;
    }
    for (size_t i = 0; i < b; i++) {
        self->riov[i].iov_base = self->buffers + i * (size_t)slot;
        self->riov[i].iov_len = (size_t)slot;
    }
    self->fd = fd;
    self->family = family;
    self->batch = batch;
    self->buffer_size = buffer_size;
    self->timestamps = timestamps;
    self->tclass = tclass;
    self->rounds = DEFAULT_ROUNDS;
    self->segment = coalesce;
    self->gro = gro;
    self->slot = slot;
    setup_receive(self);
    self->paused = 0;
    self->closed = 0;
    Py_XSETREF(self->on_batch, Py_NewRef(on_batch));
    Py_XSETREF(self->on_error, Py_NewRef(on_error));
    Py_XSETREF(self->on_blocked, Py_NewRef(on_blocked));
    memset(&self->c, 0, sizeof(self->c));
    return 0;
}

static PyMethodDef Engine_methods[] = {
    {"drain", (PyCFunction)Engine_drain, METH_NOARGS,
     "Receive every queued datagram, one on_batch call per recvmmsg; returns how many."},
    {"send", (PyCFunction)(void (*)(void))Engine_send, METH_FASTCALL,
     "send(data, addr=None) -> bool: one sendto; False when lost (counted) or handed back."},
    {"send_batch", (PyCFunction)Engine_send_batch, METH_O,
     "send_batch([(data, addr), ...]) -> int: one sendmmsg per batch; how many the kernel took."},
    {"stats", (PyCFunction)Engine_stats, METH_NOARGS, "The counters, as a dict."},
    {"set_paused", (PyCFunction)Engine_set_paused, METH_O,
     "While paused, every send is handed to on_blocked without a system call."},
    {"set_on_batch", (PyCFunction)Engine_set_on_batch, METH_O,
     "Hand the next batches to another callback (same arguments as on_batch)."},
    {"close", (PyCFunction)Engine_close, METH_NOARGS, "Forget the file descriptor (not closed)."},
    {NULL, NULL, 0, NULL},
};

static PyMemberDef Engine_members[] = {
    {"batch", T_INT, offsetof(Engine, batch), READONLY, "datagrams per system call"},
    {"buffer_size", T_INT, offsetof(Engine, buffer_size), READONLY, "bytes per receive buffer"},
    {"rounds", T_INT, offsetof(Engine, rounds), 0, "full batches per drain() at most"},
    {"paused", T_INT, offsetof(Engine, paused), READONLY, "whether sends are handed back"},
    {"segmenting", T_INT, offsetof(Engine, segment), READONLY,
     "whether send_batch coalesces runs with UDP_SEGMENT"},
    {"receive_coalescing", T_INT, offsetof(Engine, gro), READONLY,
     "whether the socket receives coalesced runs (UDP_GRO)"},
    {NULL, 0, 0, 0, NULL},
};

static PyTypeObject EngineType = {
    PyVarObject_HEAD_INIT(NULL, 0).tp_name = "tdtp.aio._datagram.Engine",
    .tp_basicsize = sizeof(Engine),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC,
    .tp_doc = "Batched UDP I/O over a borrowed non-blocking socket (recvmmsg / sendmmsg).",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)Engine_init,
    .tp_dealloc = (destructor)Engine_dealloc,
    .tp_traverse = (traverseproc)Engine_traverse,
    .tp_clear = (inquiry)Engine_clear,
    .tp_methods = Engine_methods,
    .tp_members = Engine_members,
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "tdtp.aio._datagram",
    "Batched UDP I/O for tdtp's asyncio layer: recvmmsg / sendmmsg over a borrowed socket.", -1,
    NULL, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC
PyInit__datagram(void)
{
    if (PyType_Ready(&EngineType) < 0)
        return NULL;
    PyObject *m = PyModule_Create(&module);
    if (m == NULL)
        return NULL;
    if (PyModule_AddObjectRef(m, "Engine", (PyObject *)&EngineType) < 0 ||
        PyModule_AddIntConstant(m, "MAX_BATCH", MAX_BATCH) < 0 ||
        PyModule_AddIntConstant(m, "MIN_BUFFER", MIN_BUFFER) < 0 ||
        PyModule_AddIntConstant(m, "MAX_BUFFER", MAX_BUFFER) < 0 ||
        PyModule_AddIntConstant(m, "MAX_TOTAL", MAX_TOTAL) < 0 ||
        PyModule_AddIntConstant(m, "MAX_SEGMENTS", MAX_SEGMENTS) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
