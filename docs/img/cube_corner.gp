# cube_corner.gp - the paper's section 2.6 figure: corner vertical displacement of the 1 m cube
# over time at three resolutions, both operators. Regenerate (from the repository root):
#   build/squish bench cube --out /tmp/cube_corner.csv
#   gnuplot -e "data='/tmp/cube_corner.csv'" docs/img/cube_corner.gp
if (!exists("data")) data = 'cube_corner.csv'
if (!exists("out")) out = 'docs/img/cube_corner.png'
set terminal pngcairo size 1000,560 font "DejaVu Sans,11"
set output out
set termoption noenhanced
set datafile separator ","
set key outside right top box
set grid
set xlabel "time (s)"
set ylabel "corner (1,1,1) vertical displacement (mm)"
set title "1 m cube, bottom fixed, gravity (paper sec. 2.6)\nmu = 40 kPa, lambda = 100 kPa, rho = 1000 kg/m3, Rayleigh a = 0.5/s, b = 1e-3 s"
set style line 1 lc rgb "#9ecae1" lw 2
set style line 2 lc rgb "#3182bd" lw 2
set style line 3 lc rgb "#08306b" lw 2
set style line 4 lc rgb "#fdae6b" lw 2 dt 2
set style line 5 lc rgb "#e6550d" lw 2 dt 2
set style line 6 lc rgb "#7f2704" lw 2 dt 2
plot for [c=2:7] data using 1:(1000*column(c)) with lines ls (c-1) title columnheader(c)
