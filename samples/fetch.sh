#!/usr/bin/env bash
# Fetch the project's sample data (HDRIs, OCIO config, meshes, photo plates,
# chessboard photos) from Debian packages into a local cache, verifying SHA-256.
#
#   samples/fetch.sh              fetch whatever is missing or corrupt
#   samples/fetch.sh NAME|GROUP…  only these entries (names as in manifest.tsv,
#                                 groups: hdr ocio models plates chessboard raw all)
#   samples/fetch.sh --check      verify the cache only; non-zero if incomplete
#   samples/fetch.sh --list       print the manifest names and groups
#
# Cache: $COMPOSE_SAMPLES_DIR, else ${XDG_CACHE_HOME:-$HOME/.cache}/compose/samples.
# The cache directory is printed as the last line of stdout on success;
# everything else goes to stderr.  Packages are fetched with `apt-get download`
# (nothing is installed), each .deb at most once per run, deleted afterwards.
set -euo pipefail

prog=fetch.sh
here=$(cd -- "$(dirname -- "${BASH_SOURCE[0]}")" && pwd)
manifest=${COMPOSE_SAMPLES_MANIFEST:-$here/manifest.tsv}

log()  { printf '%s\n' "$*" >&2; }
info() { log "$prog: $*"; }
err()  { log "$prog: error: $*"; }
die()  { err "$*"; exit 1; }

usage() { sed -n '2,15p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//' >&2; }

sha256() { sha256sum -- "$1" | cut -d' ' -f1; }

group_of() {  # name -> group keyword
  case $1 in
    ocio/*)       echo ocio ;;
    chessboard/*) echo chessboard ;;
    raw/*)        echo raw ;;
    *.exr)        echo hdr ;;
    *.obj|*.bez)  echo models ;;
    *)            echo plates ;;
  esac
}

# ---------------------------------------------------------------- arguments
mode=fetch
want=()
for a in "$@"; do
  case $a in
    --check) mode=check ;;
    --list)  mode=list ;;
    -h|--help) usage; exit 0 ;;
    -*) usage; die "unknown option: $a" ;;
    *) want+=("$a") ;;
  esac
done

# ---------------------------------------------------------------- manifest
[[ -r $manifest ]] || die "cannot read manifest $manifest"
names=() pkgs=() paths=() sums=()
lineno=0
while IFS=$'\t' read -r n p pth s _lic || [[ -n ${n:-} ]]; do
  lineno=$((lineno + 1))
  [[ $lineno -eq 1 || -z $n || $n == \#* ]] && continue
  [[ -n $p && $pth == /* && $s =~ ^[0-9a-f]{64}$ ]] ||
    die "$manifest:$lineno: malformed entry"
  [[ $n != /* && $n != *..* ]] || die "$manifest:$lineno: bad name '$n'"
  names+=("$n"); pkgs+=("$p"); paths+=("$pth"); sums+=("$s")
done < "$manifest"

if [[ $mode == list ]]; then
  for i in "${!names[@]}"; do
    printf '%s\t%s\n' "$(group_of "${names[$i]}")" "${names[$i]}"
  done
  exit 0
fi

# selection
sel=()
if [[ ${#want[@]} -eq 0 ]]; then
  sel=("${!names[@]}")
else
  declare -A picked=()
  for w in "${want[@]}"; do
    hit=0
    for i in "${!names[@]}"; do
      if [[ $w == all || $w == "${names[$i]}" || $w == "$(group_of "${names[$i]}")" ]]; then
        hit=1
        if [[ -z ${picked[$i]:-} ]]; then picked[$i]=1; sel+=("$i"); fi
      fi
    done
    [[ $hit -eq 1 ]] || die "no manifest entry or group named '$w' (try --list)"
  done
fi

# ---------------------------------------------------------------- cache dir
cache=${COMPOSE_SAMPLES_DIR:-${XDG_CACHE_HOME:-$HOME/.cache}/compose/samples}
if [[ $mode == check ]]; then
  [[ -d $cache ]] || { err "cache directory $cache does not exist"; exit 1; }
else
  mkdir -p -- "$cache" || die "cannot create cache directory $cache"
fi
cache=$(cd -- "$cache" && pwd)

# Returns the indices in "$@" whose cached file is missing or wrong.
# Corrupt files are reported; with remove=1 they are deleted.
bad=()
scan() {
  local remove=$1; shift
  bad=()
  local i f got
  for i in "$@"; do
    f=$cache/${names[$i]}
    if [[ ! -e $f ]]; then
      bad+=("$i")
    elif [[ ! -f $f ]]; then
      err "${names[$i]} in the cache is not a regular file"
      bad+=("$i")
    else
      got=$(sha256 "$f")
      if [[ $got != "${sums[$i]}" ]]; then
        info "cached ${names[$i]} has the wrong sha256 (expected ${sums[$i]}, got $got)${remove:+; re-fetching}"
        [[ $remove == 1 ]] && rm -f -- "$f"
        bad+=("$i")
      fi
    fi
  done
}

if [[ $mode == check ]]; then
  scan "" "${sel[@]}"
  if [[ ${#bad[@]} -gt 0 ]]; then
    for i in "${bad[@]}"; do
      log "missing: ${names[$i]} (from ${pkgs[$i]} ${paths[$i]})"
    done
    err "${#bad[@]} of ${#sel[@]} sample files missing or corrupt in $cache; run samples/fetch.sh"
    exit 1
  fi
  log "samples: ${#sel[@]} files verified in $cache"
  printf '%s\n' "$cache"
  exit 0
fi

scan 1 "${sel[@]}"
fetched=0
errors=0

if [[ ${#bad[@]} -gt 0 ]]; then
  if ! command -v apt-get >/dev/null || ! command -v dpkg-deb >/dev/null; then
    die "apt-get and dpkg-deb are required to fetch ${#bad[@]} missing sample files"
  fi

  # One fetcher at a time per cache; re-check after obtaining the lock in case
  # another run already fetched what we need.
  exec 9> "$cache/.lock"
  if command -v flock >/dev/null; then
    flock 9 2>/dev/null || true
  fi
  rm -rf -- "$cache"/.fetch.*          # leftovers of an interrupted run
  scan 1 "${bad[@]}"
fi

work=""
cleanup() { if [[ -n $work ]]; then rm -rf -- "$work"; fi; }
trap cleanup EXIT
trap 'exit 130' INT TERM

apt_opts=(-q)
[[ $EUID -eq 0 ]] && apt_opts+=(-o APT::Sandbox::User=root)
updated=0

# apt-get download PKG into DIR, updating the package lists once per run if
# apt does not know the package (or the version it knows has left the archive).
apt_download() { (cd -- "$1" && apt-get "${apt_opts[@]}" download -- "$2") >"$3" 2>&1; }
download() {
  local dir=$1 pkg=$2 logf=$3
  if apt_download "$dir" "$pkg" "$logf"; then return 0; fi
  if [[ $updated -eq 0 ]] &&
     grep -qE 'Unable to locate package|has no installation candidate|Can.t select candidate|404 +Not Found' "$logf"; then
    updated=1
    info "apt does not know $pkg; running apt-get update"
    if ! apt-get -qq update >"$logf.update" 2>&1; then
      sed 's/^/  /' "$logf.update" >&2
      err "apt-get update failed"
    fi
    if apt_download "$dir" "$pkg" "$logf"; then return 0; fi
  fi
  sed 's/^/  /' "$logf" >&2
  return 1
}

if [[ ${#bad[@]} -gt 0 ]]; then
  # group the missing entries by package, keeping manifest order
  order=()
  declare -A members=()
  for i in "${bad[@]}"; do
    p=${pkgs[$i]}
    [[ -n ${members[$p]:-} ]] || order+=("$p")
    members[$p]+="$i "
  done

  for p in "${order[@]}"; do
    read -r -a idx <<< "${members[$p]}"
    work=$(mktemp -d "$cache/.fetch.XXXXXX")
    chmod 755 "$work"
    mkdir "$work/root"
    info "downloading $p (${#idx[@]} file(s) needed)"
    if ! download "$work" "$p" "$work/apt.log"; then
      for i in "${idx[@]}"; do
        err "apt-get download $p failed; cannot fetch ${names[$i]}"
      done
      errors=$((errors + ${#idx[@]})); cleanup; work=""; continue
    fi
    debs=("$work/${p}"_*.deb)
    if [[ ! -f ${debs[0]} ]]; then
      for i in "${idx[@]}"; do
        err "apt-get download $p produced no .deb; cannot fetch ${names[$i]}"
      done
      errors=$((errors + ${#idx[@]})); cleanup; work=""; continue
    fi
    deb=${debs[0]}

    # extract only the members we need
    declare -A seen=()
    members_list=()
    for i in "${idx[@]}"; do
      m=.${paths[$i]}
      [[ -n ${seen[$m]:-} ]] || { seen[$m]=1; members_list+=("$m"); }
    done
    unset seen
    set +e
    dpkg-deb --fsys-tarfile "$deb" 2>"$work/dpkg.err" |
      tar -x -C "$work/root" --no-same-owner -f - -- "${members_list[@]}" 2>"$work/tar.err"
    st=("${PIPESTATUS[@]}")
    set -e
    if [[ ${st[0]} -ne 0 ]]; then
      sed 's/^/  /' "$work/dpkg.err" >&2
      for i in "${idx[@]}"; do
        err "cannot unpack $(basename "$deb"); cannot fetch ${names[$i]} from $p"
      done
      errors=$((errors + ${#idx[@]})); cleanup; work=""; continue
    fi
    rm -f -- "$deb"                    # large; not needed any more

    for i in "${idx[@]}"; do
      n=${names[$i]}
      src=$work/root/.${paths[$i]}
      if [[ -L $src || ! -e $src ]]; then
        if [[ -L $src ]]; then
          err "${paths[$i]} in $p is a symlink, not a file; cannot fetch $n"
        else
          err "${paths[$i]} not found in package $p ($(basename "$deb")); cannot fetch $n"
        fi
        errors=$((errors + 1)); continue
      fi
      if [[ ! -f $src ]]; then
        err "${paths[$i]} in $p is not a regular file; cannot fetch $n"
        errors=$((errors + 1)); continue
      fi
      got=$(sha256 "$src")
      if [[ $got != "${sums[$i]}" ]]; then
        err "sha256 mismatch for $n from $p (expected ${sums[$i]}, got $got)"
        rm -f -- "$src"
        errors=$((errors + 1)); continue
      fi
      dest=$cache/$n
      mkdir -p -- "$(dirname -- "$dest")"
      chmod 644 -- "$src"
      # same filesystem as the cache: the final rename is atomic
      mv -f -- "$src" "$dest.part.$$"
      mv -f -- "$dest.part.$$" "$dest"
      fetched=$((fetched + 1))
    done
    if [[ ${st[1]} -ne 0 && -s $work/tar.err ]] && ! grep -q 'Not found in archive' "$work/tar.err"; then
      sed 's/^/  /' "$work/tar.err" >&2
    fi
    cleanup; work=""
  done
fi

if [[ $errors -gt 0 ]]; then
  err "$errors of ${#sel[@]} sample files could not be fetched into $cache"
  exit 1
fi

# final verification of everything selected
scan "" "${sel[@]}"
if [[ ${#bad[@]} -gt 0 ]]; then
  for i in "${bad[@]}"; do err "${names[$i]} is still missing or corrupt in $cache"; done
  exit 1
fi
if [[ $fetched -gt 0 ]]; then
  log "samples: ${#sel[@]} files verified in $cache ($fetched fetched)"
else
  log "samples: ${#sel[@]} files verified in $cache"
fi
printf '%s\n' "$cache"
