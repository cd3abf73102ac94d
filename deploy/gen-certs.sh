#!/bin/sh
# Make a private CA and one certificate per Zenoh identity, for the TLS / mutual-TLS links
# and the access control of deploy/zenoh/*.json5 (the certificate's common name is the
# identity the routers' access control names).
#
#   deploy/gen-certs.sh DIR NAME[:DNS-or-IP,...] ...
#   deploy/gen-certs.sh /etc/radar-fusion/tls \
#       radar-fusion:fusion.site-a.example,localhost,127.0.0.1 \
#       router-a:router-a.site-a.example router-b:router-b.site-b.example \
#       fe-north fe-west fe-south display-a1 display-b1 recorder
#
# Writes DIR/ca.pem + DIR/ca.key (created once, reused on later runs) and DIR/NAME.pem +
# DIR/NAME.key for each NAME (EC P-256, extended key usage server + client, valid
# $DAYS days, default 825). The names after ':' go into subjectAltName: a certificate
# that a listener presents must name the host or address its clients connect to.
# Keep ca.key offline; each host needs ca.pem and only its own NAME.pem and NAME.key.
set -eu

[ $# -ge 2 ] || { sed -n '2,16p' "$0"; exit 2; }
dir=$1; shift
days=${DAYS:-825}
mkdir -p "$dir"
umask 077

if [ ! -f "$dir/ca.pem" ]; then
    openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -sha256 \
        -days 3650 -subj "/CN=radar-fusion CA" \
        -addext "basicConstraints=critical,CA:TRUE" \
        -addext "keyUsage=critical,keyCertSign,cRLSign" \
        -keyout "$dir/ca.key" -out "$dir/ca.pem"
    chmod 644 "$dir/ca.pem"
fi

for spec in "$@"; do
    name=${spec%%:*}
    alts=
    if [ "$spec" != "$name" ]; then
        for a in $(echo "${spec#*:}" | tr ',' ' '); do
            case $a in
                *[!0-9.]*) alts="$alts,DNS:$a" ;;   # not only digits and dots: a host name
                *) alts="$alts,IP:$a" ;;
            esac
        done
    fi
    ext=$(mktemp)
    {
        echo "basicConstraints=critical,CA:FALSE"
        echo "keyUsage=critical,digitalSignature"
        echo "extendedKeyUsage=serverAuth,clientAuth"
        # rustls checks the names of a server's certificate; clients' names are not checked
        echo "subjectAltName=DNS:$name$alts"
    } > "$ext"
    openssl req -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -sha256 \
        -subj "/CN=$name" -keyout "$dir/$name.key" -out "$dir/$name.csr"
    openssl x509 -req -in "$dir/$name.csr" -CA "$dir/ca.pem" -CAkey "$dir/ca.key" -CAcreateserial \
        -days "$days" -sha256 -extfile "$ext" -out "$dir/$name.pem"
    rm -f "$dir/$name.csr" "$ext"
    chmod 644 "$dir/$name.pem"   # the key stays 600: give it to the service's user (README)
    echo "$dir/$name.pem ($(openssl x509 -in "$dir/$name.pem" -noout -subject))"
done
