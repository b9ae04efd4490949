/* Writing text files with every error seen, and the free space of a file system, for
 * Fortran. gfortran's buffered WRITE, FLUSH and CLOSE report no error when the disk is full:
 * 24 kB written to an 8 kB file system came back with status 0 and left an 8 kB file, so an
 * .xdmf or a forces file cut short kept its final name. Here every write(2) and close(2)
 * is checked. */
#include <errno.h>
#include <fcntl.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/statvfs.h>
#include <unistd.h>

static void copy_message(int err, char *message, int capacity)
{
    const char *text = strerror(err);
    int k = 0;
    for (; k < capacity && text[k] != '\0'; ++k)
        message[k] = text[k];
    for (; k < capacity; ++k)
        message[k] = ' ';
}

/* Writes the n bytes of data to path, replacing its contents (append == 0) or after them.
 * A failed append truncates the file back to its size before it, so no partial row is left.
 * Returns 0, or the errno of the first failure with strerror's text in message (capacity
 * bytes, blank-padded for Fortran). */
int sph_write_bytes(const char *path, const char *data, long long n, int append,
                    char *message, int capacity)
{
    int fd, err = 0;
    off_t before = 0;
    struct stat status;
    fd = open(path, O_WRONLY | O_CREAT | (append ? O_APPEND : O_TRUNC), 0644);
    if (fd < 0) {
        err = errno;
        copy_message(err, message, capacity);
        return err;
    }
    if (append && fstat(fd, &status) == 0)
        before = status.st_size;
    while (n > 0) {
        ssize_t written = write(fd, data, (size_t)n);
        if (written < 0) {
            if (errno == EINTR)
                continue;
            err = errno;
            break;
        }
        data += written;
        n -= written;
    }
    if (err != 0 && append && ftruncate(fd, before) != 0) {
        /* the file keeps a partial row; the error reported is the write's */
    }
    if (close(fd) != 0 && err == 0)
        err = errno;
    if (err != 0)
        copy_message(err, message, capacity);
    return err;
}

/* Bytes available to an unprivileged writer on the file system holding path, or -1 when it
 * cannot be asked. */
long long sph_free_bytes(const char *path)
{
    struct statvfs fs;
    if (statvfs(path, &fs) != 0)
        return -1;
    return (long long)fs.f_bavail * (long long)fs.f_frsize;
}
