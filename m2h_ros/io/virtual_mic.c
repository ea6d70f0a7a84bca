/* A virtual ALSA capture device: plays a raw file of interleaved float32 frames into the capture
 * stream at real-time pace, as a microphone would deliver them (m2h_ros/io/virtual_mic.py builds and
 * configures it). Sample i of the file becomes readable at start + (i + 1) / rate; a reader that
 * falls a whole buffer behind gets an overrun (-EPIPE), and after it the stream resumes at the
 * sample due now, so the samples it missed are lost as with a real card. After the file's end the
 * device delivers silence. At each start it appends the CLOCK_REALTIME nanoseconds of sample 0's
 * position in time (one line) to `start_file`, so a test can check capture-time stamps.
 *
 * ALSA configuration:
 *   pcm_type.m2hmic { lib "/path/libasound_module_pcm_m2hmic.so" }
 *   pcm.NAME { type m2hmic file "/path/signal.f32" rate 48000 channels 4 start_file "/path/starts" }
 */
#include <alsa/asoundlib.h>
#include <alsa/pcm_external.h>
#include <errno.h>
#include <poll.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/timerfd.h>
#include <time.h>
#include <unistd.h>

typedef struct {
    snd_pcm_ioplug_t io;
    FILE *source;
    char *start_file;
    unsigned int rate, channels;
    int timer_fd;
    uint64_t first_start_ns; /* CLOCK_MONOTONIC of the first start: file sample 0 */
    uint64_t start_ns;       /* of the current run (after an overrun the stream is restarted) */
    uint64_t base;           /* file sample at the current run's start */
    uint64_t read;           /* samples handed to the reader in this run */
    int running;
} vmic_t;

static uint64_t now_ns(clockid_t clock) {
    struct timespec t;
    clock_gettime(clock, &t);
    return (uint64_t)t.tv_sec * 1000000000ull + (uint64_t)t.tv_nsec;
}

static uint64_t frames_since(const vmic_t *m, uint64_t since_ns) {
    return (uint64_t)((unsigned __int128)(now_ns(CLOCK_MONOTONIC) - since_ns) * m->rate / 1000000000ull);
}

static int vmic_start(snd_pcm_ioplug_t *io) {
    vmic_t *m = io->private_data;
    uint64_t mono = now_ns(CLOCK_MONOTONIC);
    if (!m->first_start_ns) {
        uint64_t real = now_ns(CLOCK_REALTIME);
        m->first_start_ns = mono;
        if (m->start_file) {
            FILE *f = fopen(m->start_file, "a");
            if (f) {
                fprintf(f, "%llu\n", (unsigned long long)real);
                fclose(f);
            }
        }
    }
    m->start_ns = mono;
    /* samples that passed while stopped are gone */
    m->base = (uint64_t)((unsigned __int128)(mono - m->first_start_ns) * m->rate / 1000000000ull);
    m->read = 0;
    uint64_t period_ns = (uint64_t)io->period_size * 1000000000ull / m->rate;
    struct itimerspec its = {{period_ns / 1000000000ull, period_ns % 1000000000ull},
                             {period_ns / 1000000000ull, period_ns % 1000000000ull}};
    timerfd_settime(m->timer_fd, 0, &its, NULL);
    m->running = 1;
    return 0;
}

static int vmic_stop(snd_pcm_ioplug_t *io) {
    vmic_t *m = io->private_data;
    struct itimerspec off = {{0, 0}, {0, 0}};
    timerfd_settime(m->timer_fd, 0, &off, NULL);
    m->running = 0;
    return 0;
}

static int vmic_prepare(snd_pcm_ioplug_t *io) {
    vmic_stop(io); /* after an overrun ALSA prepares the stream again; the next start resumes it */
    ((vmic_t *)io->private_data)->read = 0;
    return 0;
}

static snd_pcm_sframes_t vmic_pointer(snd_pcm_ioplug_t *io) {
    vmic_t *m = io->private_data;
    if (!m->running)
        return (snd_pcm_sframes_t)(m->read % io->buffer_size);
    uint64_t produced = frames_since(m, m->start_ns);
    if (produced - m->read >= io->buffer_size)
        return -EPIPE; /* the reader fell a whole buffer behind: overrun */
    return (snd_pcm_sframes_t)(produced % io->buffer_size);
}

static snd_pcm_sframes_t vmic_transfer(snd_pcm_ioplug_t *io, const snd_pcm_channel_area_t *areas,
                                       snd_pcm_uframes_t offset, snd_pcm_uframes_t size) {
    vmic_t *m = io->private_data;
    float *dst = (float *)((char *)areas->addr + (areas->first + areas->step * offset) / 8);
    size_t frame_bytes = (size_t)m->channels * sizeof(float);
    size_t got = 0;
    if (fseeko(m->source, (off_t)((m->base + m->read) * frame_bytes), SEEK_SET) == 0)
        got = fread(dst, frame_bytes, size, m->source);
    memset(dst + got * m->channels, 0, (size - got) * frame_bytes); /* past the end: silence */
    m->read += size;
    return (snd_pcm_sframes_t)size;
}

static int vmic_poll_revents(snd_pcm_ioplug_t *io, struct pollfd *pfd, unsigned int nfds,
                             unsigned short *revents) {
    vmic_t *m = io->private_data;
    uint64_t expirations;
    (void)pfd;
    (void)nfds;
    while (read(m->timer_fd, &expirations, sizeof expirations) > 0) {
    }
    *revents = POLLIN;
    return 0;
}

static int vmic_close(snd_pcm_ioplug_t *io) {
    vmic_t *m = io->private_data;
    close(m->timer_fd);
    fclose(m->source);
    free(m->start_file);
    free(m);
    return 0;
}

static const snd_pcm_ioplug_callback_t vmic_callbacks = {
    .start = vmic_start,
    .stop = vmic_stop,
    .prepare = vmic_prepare,
    .pointer = vmic_pointer,
    .transfer = vmic_transfer,
    .poll_revents = vmic_poll_revents,
    .close = vmic_close,
};

SND_PCM_PLUGIN_DEFINE_FUNC(m2hmic) {
    snd_config_iterator_t i, next;
    const char *file = NULL, *start_file = NULL;
    long rate = 0, channels = 0;
    int err;
    (void)root;
    snd_config_for_each(i, next, conf) {
        snd_config_t *n = snd_config_iterator_entry(i);
        const char *id;
        if (snd_config_get_id(n, &id) < 0)
            continue;
        if (!strcmp(id, "comment") || !strcmp(id, "type") || !strcmp(id, "hint"))
            continue;
        if (!strcmp(id, "file") && snd_config_get_string(n, &file) >= 0)
            continue;
        if (!strcmp(id, "start_file") && snd_config_get_string(n, &start_file) >= 0)
            continue;
        if (!strcmp(id, "rate") && snd_config_get_integer(n, &rate) >= 0)
            continue;
        if (!strcmp(id, "channels") && snd_config_get_integer(n, &channels) >= 0)
            continue;
        SNDERR("m2hmic: unknown or malformed field %s", id);
        return -EINVAL;
    }
    if (!file || rate <= 0 || channels <= 0) {
        SNDERR("m2hmic: file, rate and channels are required");
        return -EINVAL;
    }
    if (stream != SND_PCM_STREAM_CAPTURE)
        return -EINVAL; /* a microphone only */
    vmic_t *m = calloc(1, sizeof *m);
    if (!m)
        return -ENOMEM;
    m->source = fopen(file, "rb");
    if (!m->source) {
        SNDERR("m2hmic: cannot open %s", file);
        free(m);
        return -ENOENT;
    }
    m->start_file = start_file ? strdup(start_file) : NULL;
    m->rate = (unsigned int)rate;
    m->channels = (unsigned int)channels;
    m->timer_fd = timerfd_create(CLOCK_MONOTONIC, TFD_NONBLOCK | TFD_CLOEXEC);
    m->io.version = SND_PCM_IOPLUG_VERSION;
    m->io.name = "m2h virtual microphone";
    m->io.callback = &vmic_callbacks;
    m->io.private_data = m;
    m->io.poll_fd = m->timer_fd;
    m->io.poll_events = POLLIN;
    m->io.mmap_rw = 0;
    err = snd_pcm_ioplug_create(&m->io, name, stream, mode);
    if (err < 0) {
        close(m->timer_fd);
        fclose(m->source);
        free(m->start_file);
        free(m);
        return err;
    }
    /* mmap first: PortAudio's mmap path recovers from an overrun (restarts, flags it); its
     * read/write path leaves the stream stopped. ALSA fills the mmap buffer through transfer(). */
    static const unsigned int access[] = {SND_PCM_ACCESS_MMAP_INTERLEAVED, SND_PCM_ACCESS_RW_INTERLEAVED};
    static const unsigned int format[] = {SND_PCM_FORMAT_FLOAT_LE};
    if ((err = snd_pcm_ioplug_set_param_list(&m->io, SND_PCM_IOPLUG_HW_ACCESS, 2, access)) < 0 ||
        (err = snd_pcm_ioplug_set_param_list(&m->io, SND_PCM_IOPLUG_HW_FORMAT, 1, format)) < 0 ||
        (err = snd_pcm_ioplug_set_param_minmax(&m->io, SND_PCM_IOPLUG_HW_CHANNELS, m->channels, m->channels)) < 0 ||
        (err = snd_pcm_ioplug_set_param_minmax(&m->io, SND_PCM_IOPLUG_HW_RATE, m->rate, m->rate)) < 0 ||
        (err = snd_pcm_ioplug_set_param_minmax(&m->io, SND_PCM_IOPLUG_HW_PERIOD_BYTES, 64, 1 << 20)) < 0 ||
        (err = snd_pcm_ioplug_set_param_minmax(&m->io, SND_PCM_IOPLUG_HW_PERIODS, 2, 1024)) < 0 ||
        (err = snd_pcm_ioplug_set_param_minmax(&m->io, SND_PCM_IOPLUG_HW_BUFFER_BYTES, 128, 1 << 24)) < 0) {
        snd_pcm_ioplug_delete(&m->io);
        return err;
    }
    *pcmp = m->io.pcm;
    return 0;
}

SND_PCM_PLUGIN_SYMBOL(m2hmic);
