#!/bin/bash
# The simulated house's speech model: PocketSphinx's en-us model (Debian's pocketsphinx-en-us)
# MAP-adapted to the simulation's voices (espeak-ng) in the simulated room, with sphinxtrain's
# bw and map_adapt (docs/speech.md, "The simulated house's model"). Everything comes from Debian
# packages; nothing is downloaded. Deterministic: the same inputs give the same model.
#
#   adapt.sh RENDER SENTENCES OUT [SEED]
#
# RENDER is icars-render-adaptation; OUT/en-us is the adapted model and OUT/cmudict-en-us.dict
# the dictionary, the layout RecognizerOptions::model_dir takes. The work files (recordings,
# features, statistics) are removed at the end unless ICARS_KEEP_ADAPTATION is set.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
render=$1
sentences=$2
out=$3
seed=${4:-20240601}
voices=(en-us en-us+f3 en)
stock=/usr/share/pocketsphinx/model/en-us
st=/usr/lib/sphinxtrain
for tool in "$st/bw" "$st/map_adapt" "$st/mk_s2sendump" "$(command -v sphinx_fe)" "$(command -v pocketsphinx_mdef_convert)"; do
  [ -x "$tool" ] || { echo "adapt.sh: $tool missing (scripts/install-deps.sh installs sphinxtrain and sphinxbase-utils)" >&2; exit 1; }
done
[ -f "$stock/en-us/sendump" ] || { echo "adapt.sh: $stock/en-us missing (apt install pocketsphinx-en-us)" >&2; exit 1; }

work="$out/work"
rm -rf "$work" "$out/en-us" "$out/en-us.tmp"
mkdir -p "$work/accum"
cd "$work"
# 1. Recordings, and the files bw reads.
"$render" "$sentences" data "$seed" "${voices[@]}"
# 2. The stock model with a text mdef and float mixture weights.
cp -r "$stock/en-us" base
/usr/bin/python3 "$here/sendump_to_mixw.py" base/sendump base/mixture_weights
pocketsphinx_mdef_convert -text base/mdef base/mdef.txt 2>/dev/null
# 3. Features, with the model's front end.
sphinx_fe -argfile base/feat.params -samprate 16000 -c data/adapt.fileids -di data -do data \
  -ei wav -eo mfc -mswav yes > fe.log 2>&1
# 4. Statistics, with the feature options of base/feat.params (CMN as the decoder does it).
"$st/bw" -hmmdir base -moddeffn base/mdef.txt -ts2cbfn .ptm. -feat 1s_c_d_dd \
  -svspec 0-12/13-25/26-38 -cmn batch -agc none -varnorm no \
  -cmninit "$(sed -n 's/^-cmninit //p' base/feat.params)" \
  -dictfn "$stock/cmudict-en-us.dict" -ctlfn data/adapt.fileids -lsnfn data/adapt.transcription \
  -cepdir data -accumdir accum > bw.log 2>&1
aligned=$(grep -c '^utt>' bw.log || true)
total=$(wc -l < data/adapt.fileids)
[ "$aligned" -eq "$total" ] || { echo "adapt.sh: bw aligned $aligned of $total recordings (see $work/bw.log)" >&2; exit 1; }
# 5. MAP into a copy of the model, then its sendump (-mwfloor 1e-8 keeps the small weights
#    Debian's sendump has; the default 1e-5 would clip them).
cp -r base adapted
"$st/map_adapt" -moddeffn base/mdef.txt -ts2cbfn .ptm. -meanfn base/means -varfn base/variances \
  -mixwfn base/mixture_weights -tmatfn base/transition_matrices -accumdir accum \
  -mapmeanfn adapted/means -mapvarfn adapted/variances \
  -mapmixwfn adapted/mixture_weights -maptmatfn adapted/transition_matrices > map.log 2>&1
"$st/mk_s2sendump" -pocketsphinx yes -mwfloor 1e-8 -moddeffn adapted/mdef.txt \
  -mixwfn adapted/mixture_weights -sendumpfn adapted/sendump > sendump.log 2>&1
rm adapted/mixture_weights adapted/mdef.txt
# 6. In place, the model last: its presence says the model is complete.
cd "$out"
ln -sfn "$stock/cmudict-en-us.dict" cmudict-en-us.dict
mv "$work/adapted" en-us.tmp
mv en-us.tmp en-us
[ -n "${ICARS_KEEP_ADAPTATION:-}" ] || rm -rf "$work"
echo "adapt.sh: $out/en-us adapted with $total recordings"
