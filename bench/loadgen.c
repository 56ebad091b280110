/* loadgen: a lean RTU-over-TCP load client in C, so that the client costs the server's measurement nothing.

   A Python client spends 20-30 us of its own per request, as much as the servers it measures; this one
   spends about 2. It opens CONNS connections to HOST:PORT, spread over the ports given, each with at most
   one request outstanding (an RTU master waits for each answer), on one thread with epoll. Each
   connection sends its requests in turn (a list of frames, round robin) and checks every reply: its
   length (from the function code), its CRC, and its first two bytes (address and function).

   --rate HZ paces each connection: request k is due at start + k / HZ (a master's polling cycle), sent at
   that time or when the previous reply came, whichever is later. --due-us US is the time each reply is
   due after its request (a real line's transaction time): the lateness of each reply (latency - due) is
   reported too. --dump PATH writes every measured latency (us, one a line, in the order the replies came)
   to PATH, for a histogram of them, or the rhythm of the slow ones.

   Prints one JSON object: requests, seconds, req_s, latency percentiles (us), the fewest and most requests
   any connection got through (fairness), and lateness percentiles when --due-us is given.

   Build: cc -O2 -o loadgen bench/loadgen.c   (bench/_common.py builds it on first use)
   Use:   loadgen --port 5020 --conns 4 --seconds 5 --frame 010320010001DFCA
*/
#define _GNU_SOURCE
#include <errno.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <arpa/inet.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#define MAX_FRAMES 64
#define MAX_PORTS 1024
#define BUF 512

typedef struct {
    int fd;
    int frame;            /* index of the next frame to send */
    int outstanding;      /* 1 while a request waits for its reply */
    double sent_at;       /* when the outstanding request went */
    double next_due;      /* paced: when the next request is due */
    long done;            /* replies received */
    unsigned char buf[BUF];
    int have;
} conn_t;

static unsigned char frames[MAX_FRAMES][256];
static int frame_len[MAX_FRAMES];
static int nframes;

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static uint16_t crc16(const unsigned char *p, int n) {
    uint16_t crc = 0xFFFF;
    for (int i = 0; i < n; i++) {
        crc ^= p[i];
        for (int b = 0; b < 8; b++) crc = (crc & 1) ? (crc >> 1) ^ 0xA001 : crc >> 1;
    }
    return crc;
}

/* The length a reply will have once its first three bytes are in; 0 if not known yet, -1 if no C20 reply. */
static int reply_length(const unsigned char *p, int have) {
    if (have < 2) return 0;
    unsigned char fn = p[1];
    if (fn & 0x80) return 5;
    if (fn == 0x06 || fn == 0x10) return 8;
    if (fn == 0x03) return have < 3 ? 0 : 5 + p[2];
    return -1;
}

static int hexval(char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

static void add_frame(const char *hex) {
    if (nframes == MAX_FRAMES) { fprintf(stderr, "loadgen: at most %d frames\n", MAX_FRAMES); exit(2); }
    int n = 0;
    for (const char *c = hex; *c; c += 2) {
        if (!c[1] || hexval(c[0]) < 0 || hexval(c[1]) < 0 || n == 256) {
            fprintf(stderr, "loadgen: bad frame %s\n", hex);
            exit(2);
        }
        frames[nframes][n++] = (unsigned char)(hexval(c[0]) * 16 + hexval(c[1]));
    }
    frame_len[nframes++] = n;
}

static int cmp(const void *a, const void *b) {
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

static double pct(const double *v, long n, double p) {
    if (n == 0) return 0;
    long k = (long)(p / 100.0 * (n - 1) + 0.5);
    return v[k];
}

static void send_next(conn_t *c, double t) {
    const unsigned char *f = frames[c->frame];
    ssize_t w = send(c->fd, f, frame_len[c->frame], MSG_NOSIGNAL);
    if (w != frame_len[c->frame]) { perror("loadgen: send"); exit(1); }
    c->outstanding = 1;
    c->sent_at = t;
}

int main(int argc, char **argv) {
    const char *host = "127.0.0.1";
    const char *dump = NULL;
    int ports[MAX_PORTS], nports = 0, conns = 1;
    long requests = 0;
    double seconds = 0, rate = 0, due_us = -1, warmup = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!v) { fprintf(stderr, "loadgen: %s needs a value\n", a); return 2; }
        if (!strcmp(a, "--host")) host = v;
        else if (!strcmp(a, "--port")) {
            if (nports == MAX_PORTS) { fprintf(stderr, "loadgen: at most %d ports\n", MAX_PORTS); return 2; }
            ports[nports++] = atoi(v);
        }
        else if (!strcmp(a, "--conns")) conns = atoi(v);
        else if (!strcmp(a, "--requests")) requests = atol(v);
        else if (!strcmp(a, "--seconds")) seconds = atof(v);
        else if (!strcmp(a, "--warmup")) warmup = atof(v);
        else if (!strcmp(a, "--rate")) rate = atof(v);
        else if (!strcmp(a, "--due-us")) due_us = atof(v);
        else if (!strcmp(a, "--frame")) add_frame(v);
        else if (!strcmp(a, "--dump")) dump = v;
        else { fprintf(stderr, "loadgen: unknown option %s\n", a); return 2; }
        i++;
    }
    if (!nports || !nframes || conns < 1 || (!requests && seconds <= 0)) {
        fprintf(stderr, "usage: loadgen --port P [--port P2 ...] --frame HEX [--frame HEX ...] [--conns N]\n"
                        "               (--requests N | --seconds S) [--warmup S] [--rate HZ] [--due-us US]\n"
                        "               [--dump PATH]\n");
        return 2;
    }
    conn_t *cs = calloc(conns, sizeof(conn_t));
    int ep = epoll_create1(0);
    for (int i = 0; i < conns; i++) {
        struct sockaddr_in sa = {0};
        sa.sin_family = AF_INET;
        sa.sin_port = htons(ports[i % nports]);
        inet_pton(AF_INET, host, &sa.sin_addr);
        int fd = socket(AF_INET, SOCK_STREAM, 0);
        int one = 1;
        setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
        if (connect(fd, (struct sockaddr *)&sa, sizeof sa)) { perror("loadgen: connect"); return 1; }
        cs[i].fd = fd;
        cs[i].frame = i % nframes;
        struct epoll_event ev = {.events = EPOLLIN, .data.u32 = (uint32_t)i};
        epoll_ctl(ep, EPOLL_CTL_ADD, fd, &ev);
    }
    long cap = requests ? requests + conns : 1 << 20;
    double *lat = malloc(cap * sizeof(double));
    long nlat = 0, sent = 0, total = 0;
    double t0 = now(), measure_from = t0 + warmup;
    double end = seconds > 0 ? measure_from + seconds : 1e300;
    for (int i = 0; i < conns; i++) {
        cs[i].next_due = t0 + (rate > 0 ? (double)i / conns / rate : 0);  /* spread the first polls over a cycle */
        if (rate <= 0) { send_next(&cs[i], now()); sent++; }
    }
    int open = conns;
    struct epoll_event evs[256];
    while (open > 0) {
        double t = now();
        int stopping = t >= end || (requests && sent >= requests);
        int timeout = -1;
        if (rate > 0 && !stopping) {
            double soonest = 1e300;
            for (int i = 0; i < conns; i++) {
                conn_t *c = &cs[i];
                if (c->outstanding) continue;
                if (c->next_due <= t) { send_next(c, t); sent++; c->next_due += 1.0 / rate; if (c->next_due < t) c->next_due = t; }
                else if (c->next_due < soonest) soonest = c->next_due;
            }
            if (soonest < 1e300) {
                double wait_ms = (soonest - now()) * 1000;
                timeout = wait_ms <= 0 ? 0 : (int)wait_ms;  /* wake up to 1 ms early, then spin the rest */
            }
        }
        if (stopping) {
            int waiting = 0;
            for (int i = 0; i < conns; i++) waiting += cs[i].outstanding;
            if (!waiting) break;
            timeout = 5000;
        }
        if (seconds > 0 && !stopping) {
            double left_ms = (end - t) * 1000;
            if (timeout < 0 || timeout > left_ms) timeout = left_ms > 0 ? (int)left_ms + 1 : 0;
        }
        int n = epoll_wait(ep, evs, 256, timeout);
        if (n < 0) { if (errno == EINTR) continue; perror("loadgen: epoll"); return 1; }
        if (n == 0 && stopping) { fprintf(stderr, "loadgen: replies missing after 5 s\n"); return 1; }
        for (int e = 0; e < n; e++) {
            conn_t *c = &cs[evs[e].data.u32];
            ssize_t r = recv(c->fd, c->buf + c->have, BUF - c->have, 0);
            if (r <= 0) { fprintf(stderr, "loadgen: the server closed a connection\n"); return 1; }
            c->have += r;
            int want = reply_length(c->buf, c->have);
            if (want < 0) { fprintf(stderr, "loadgen: not a C20 reply\n"); return 1; }
            if (want == 0 || c->have < want) continue;
            double t1 = now();
            const unsigned char *f = frames[c->frame];
            uint16_t crc = crc16(c->buf, want - 2);
            if (c->have != want || !c->outstanding || c->buf[0] != f[0] || (c->buf[1] & 0x7F) != f[1]
                || c->buf[want - 2] != (crc & 0xFF) || c->buf[want - 1] != (crc >> 8)) {
                fprintf(stderr, "loadgen: bad reply (%d bytes) to frame %d\n", c->have, c->frame);
                return 1;
            }
            if (c->buf[1] & 0x80) { fprintf(stderr, "loadgen: exception 0x%02X to frame %d\n", c->buf[2], c->frame); return 1; }
            c->have = 0;
            c->outstanding = 0;
            if (c->sent_at >= measure_from && c->sent_at < end) {
                if (nlat == cap) { cap *= 2; lat = realloc(lat, cap * sizeof(double)); }
                lat[nlat++] = (t1 - c->sent_at) * 1e6;
                c->done++;
            }
            total++;
            c->frame = (c->frame + 1) % nframes;
            int stop_now = t1 >= end || (requests && sent >= requests);
            if (!stop_now && rate <= 0) { send_next(c, now()); sent++; }
        }
    }
    double elapsed = (seconds > 0 ? (now() < end ? now() : end) - measure_from : now() - t0);
    long fewest = -1, most = 0;
    for (int i = 0; i < conns; i++) {
        if (fewest < 0 || cs[i].done < fewest) fewest = cs[i].done;
        if (cs[i].done > most) most = cs[i].done;
        close(cs[i].fd);
    }
    if (dump) {  /* in the order the replies came: a rhythm in the slow ones shows */
        FILE *out = fopen(dump, "w");
        if (!out) { perror("loadgen: --dump"); return 1; }
        for (long i = 0; i < nlat; i++) fprintf(out, "%.1f\n", lat[i]);
        fclose(out);
    }
    qsort(lat, nlat, sizeof(double), cmp);
    printf("{\"requests\": %ld, \"seconds\": %.6f, \"req_s\": %.1f, \"p50_us\": %.1f, \"p90_us\": %.1f, "
           "\"p99_us\": %.1f, \"p999_us\": %.1f, \"max_us\": %.1f, \"fewest\": %ld, \"most\": %ld",
           nlat, elapsed, nlat / elapsed, pct(lat, nlat, 50), pct(lat, nlat, 90), pct(lat, nlat, 99),
           pct(lat, nlat, 99.9), nlat ? lat[nlat - 1] : 0, fewest, most);
    if (due_us >= 0) {
        for (long i = 0; i < nlat; i++) lat[i] -= due_us;  /* sorted still: lateness = latency - due */
        long within = 0;
        for (long i = 0; i < nlat; i++) within += lat[i] <= 1000 && lat[i] >= -1000;
        printf(", \"late_p50_us\": %.1f, \"late_p99_us\": %.1f, \"late_p999_us\": %.1f, \"late_max_us\": %.1f, "
               "\"early_max_us\": %.1f, \"within_1ms\": %ld",
               pct(lat, nlat, 50), pct(lat, nlat, 99), pct(lat, nlat, 99.9), nlat ? lat[nlat - 1] : 0,
               nlat ? -lat[0] : 0, within);
    }
    printf("}\n");
    return 0;
}
