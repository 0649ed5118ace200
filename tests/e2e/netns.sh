# Source first (before lib.sh) in a test that must run entirely inside a private network
# namespace with only loopback: Aravis discovery (commonlight cameras, serve-gige clients)
# broadcasts on every interface, and tests may only talk to loopback. Re-executes the script
# under `unshare -n` (or `unshare -rn` where only user namespaces are allowed), brings lo up, and
# skips (77) when neither is permitted.
if [[ -z ${COMMONLIGHT_IN_PRIVATE_NETNS:-} ]]; then
    for unshare_args in -n -rn; do
        if unshare $unshare_args true 2>/dev/null; then
            COMMONLIGHT_IN_PRIVATE_NETNS=1 exec unshare $unshare_args -- bash "$0" "$@"
        fi
    done
    echo "SKIP: cannot make a private network namespace (unshare -n needs CAP_SYS_ADMIN or user namespaces)" >&2
    exit 77
fi
ip link set lo up 2>/dev/null || { echo "SKIP: cannot bring lo up in the private network namespace" >&2; exit 77; }
