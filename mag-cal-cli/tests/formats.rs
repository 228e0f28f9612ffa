//! Log formats seen in the wild, end to end: a real recording
//! (`icm20948_mag_300.csv`, read in place) printed the way sketches and
//! loggers print it (labelled values of one or several sensors, metadata
//! before a header, wide rows without a header, MotionCal `Raw:` lines)
//! calibrates as the plain file does, and the report names what it took;
//! what cannot be told apart is refused with what was found (exit 2).

mod common;

use common::{magcal, read_xyz, real, temp_file};
use serde_json::Value;

/// The ICM-20948 recording: its path and rows (integer counts).
fn icm() -> (String, Vec<[f64; 3]>) {
    let path = real("icm20948_mag_300.csv");
    let rows = read_xyz(&path);
    assert_eq!(rows.len(), 300);
    (path, rows)
}

fn vec3(v: &Value) -> [f64; 3] {
    let a = v.as_array().expect("array");
    [0, 1, 2].map(|i| a[i].as_f64().expect("number"))
}

/// Asserts that a fit JSON has the hard iron and field strength of
/// `reference` to within 1e-9 of their size, and uses the same rows.
fn assert_same_fit(v: &Value, reference: &Value, what: &str) {
    let (b, b0) = (vec3(&v["hard_iron"]), vec3(&reference["hard_iron"]));
    for (x, y) in b.iter().zip(b0) {
        assert!(
            (x - y).abs() <= 1e-9 * y.abs().max(1.0),
            "{what}: {b:?} vs {b0:?}"
        );
    }
    let (f, f0) = (
        v["field_strength"].as_f64().expect("field"),
        reference["field_strength"].as_f64().expect("field"),
    );
    assert!((f - f0).abs() <= 1e-9 * f0, "{what}: {f} vs {f0}");
    assert_eq!(v["samples_used"], reference["samples_used"], "{what}");
}

/// A number as a sketch prints a float with two decimals
/// (`Serial.print(x)`).
fn two(v: f64) -> String {
    format!("{v:.2}")
}

/// SparkFun's `printFormattedFloat(val, 5, 2)`: sign, zero-padded to five
/// digits, two decimals (`-00231.00`, ` 00029.00`).
fn sparkfun(v: f64) -> String {
    let sign = if v < 0.0 { '-' } else { ' ' };
    format!("{sign}{:08.2}", v.abs())
}

/// The formats: a file name, the rows printed so, and the columns line the
/// report must show.
fn labelled_formats(rows: &[[f64; 3]]) -> Vec<(&'static str, String, &'static str)> {
    let each = |f: &dyn Fn(usize, &[f64; 3]) -> String| -> String {
        rows.iter().enumerate().map(|(i, r)| f(i, r)).collect()
    };
    vec![
        (
            "mx_my_mz.txt",
            each(&|_, [x, y, z]| format!("Mx {x} My {y} Mz {z}\n")),
            "Mx,My,Mz (labelled values)",
        ),
        // Adafruit's unified-sensor examples (LSM303, LIS2MDL, ...).
        (
            "adafruit_ut.txt",
            format!(
                "Magnetometer Test\n\n{}",
                each(&|_, [x, y, z]| format!(
                    "X: {}  Y: {}  Z: {}  uT\n",
                    two(*x),
                    two(*y),
                    two(*z)
                ))
            ),
            "X (uT),Y (uT),Z (uT) (labelled values)",
        ),
        (
            "adafruit_utesla.txt",
            each(&|_, [x, y, z]| {
                format!(
                    "Mag X: {} \tY: {} \tZ: {} uTesla \r\n",
                    two(*x),
                    two(*y),
                    two(*z)
                )
            }),
            "Mag X (uTesla),Mag Y (uTesla),Mag Z (uTesla) (labelled values)",
        ),
        // Adafruit's ICM-20948 example: a banner, then one line per sensor.
        (
            "adafruit_icm20948.txt",
            format!(
                "Adafruit ICM20948 test!\nICM20948 Found!\nAccelerometer range set to: +-4G\n\
                 Accelerometer data rate divisor set to: 20\n\
                 Accelerometer data rate (Hz) is approximately: 53.57\n\
                 Gyro range set to: 500 degrees/s\nGyro data rate divisor set to: 10\n\
                 Gyro data rate (Hz) is approximately: 100.00\n\
                 Magnetometer data rate set to: 100 Hz\n\n{}",
                each(&|i, [x, y, z]| format!(
                    "\t\tTemperature {} deg C\n\
                     \t\tAccel X: {} \tY: {} \tZ: {} m/s^2 \n\
                     \t\tGyro X: {} \tY: {} \tZ: {} radians/s \n\n\
                     \t\tMag X: {} \tY: {} \tZ: {} uT\n",
                    two(25.0 + (i % 7) as f64 * 0.1),
                    two(0.1 * (i % 5) as f64),
                    two(-0.2),
                    two(9.81),
                    two(0.01 * (i % 3) as f64),
                    two(0.02),
                    two(-0.03),
                    two(*x),
                    two(*y),
                    two(*z)
                ))
            ),
            "Mag X (uT),Mag Y (uT),Mag Z (uT) (labelled values)",
        ),
        // All sensors on one line.
        (
            "one_line.txt",
            each(&|i, [x, y, z]| {
                format!(
                    "t={} ax=0.12 ay=-0.05 az=9.79 gx=0.01 gy=-0.02 gz=0.00 mx={x} my={y} mz={z}\n",
                    i * 20
                )
            }),
            "mx,my,mz (labelled values)",
        ),
        (
            "acc_gyro_mag.txt",
            each(&|_, [x, y, z]| format!("Acc: 0.12 -0.05 9.79 Gyro: 1 2 3 Mag: {x} {y} {z}\n")),
            "Mag x,Mag y,Mag z (labelled values)",
        ),
        // SparkFun's ICM-20948 Example1_Basics.
        (
            "sparkfun_scaled.txt",
            each(&|_, [x, y, z]| {
                format!(
                    "Scaled. Acc (mg) [ {}, {}, {} ], Gyr (DPS) [ {}, {}, {} ], Mag (uT) [ {}, \
                     {}, {} ], Tmp (C) [ {} ]\n",
                    sparkfun(-12.21),
                    sparkfun(4.39),
                    sparkfun(1008.79),
                    sparkfun(-0.11),
                    sparkfun(0.53),
                    sparkfun(-0.08),
                    sparkfun(*x),
                    sparkfun(*y),
                    sparkfun(*z),
                    sparkfun(29.03)
                )
            }),
            "Mag x (uT),Mag y (uT),Mag z (uT) (labelled values)",
        ),
        // Kris Winer's MPU-9250 sketch: milli-g (mg) and milligauss (mG).
        (
            "mpu9250_mg.txt",
            each(&|_, [x, y, z]| {
                format!(
                    "ax = 12 ay = 4 az = 1000 mg\ngx = 0.1 gy = 0.2 gz = 0.3 deg/s\n\
                     mx = {x} my = {y} mz = {z} mG\nq0 = 1 qx = 0 qy = 0 qz = 0\n"
                )
            }),
            "mx (mG),my (mG),mz (mG) (labelled values)",
        ),
    ]
}

/// Every labelled format calibrates as the plain file, in both reports, and
/// names the values it took; lines of other sensors are counted as skipped.
#[test]
fn labelled_formats_calibrate_as_the_plain_file() {
    let (path, rows) = icm();
    let reference = magcal(&["fit", &path, "--format", "json"]).json();
    for (name, text, columns) in labelled_formats(&rows) {
        let file = temp_file(name, &text);
        let run = magcal(&["fit", &file, "--format", "json"]);
        assert_same_fit(&run.json(), &reference, name);
        // The JSON report says on stderr which values it took, and how
        // many lines it skipped.
        let mut notes = run.stderr.lines();
        assert_eq!(
            notes.next(),
            Some(format!("magcal: note: columns {columns}").as_str()),
            "{name}: {}",
            run.stderr
        );
        let other_lines = text.lines().filter(|l| !l.trim().is_empty()).count() - 300;
        match notes.next() {
            None => assert_eq!(other_lines, 0, "{name}"),
            Some(note) => {
                let lines = if other_lines == 1 { "line" } else { "lines" };
                assert!(
                    note.starts_with(&format!(
                        "magcal: note: input: {other_lines} {lines} without a magnetometer \
                         reading skipped: line 1: '"
                    )),
                    "{name}: {note}"
                );
            }
        }
        // The text report names them on its columns line.
        let text = magcal(&["fit", &file]);
        assert_eq!(text.code, 0, "{name}: {}", text.stderr);
        assert!(text.stderr.is_empty(), "{name}: {}", text.stderr);
        assert!(
            text.stdout
                .contains(&format!("\n  columns       {columns}\n")),
            "{name}: {}",
            text.stdout
        );
    }
}

/// A logger's metadata before the header: the header is found, the
/// metadata skipped and named.
#[test]
fn metadata_before_the_header() {
    let (path, rows) = icm();
    let reference = magcal(&["fit", &path, "--format", "json"]).json();
    let mut text = String::from("Fs,50.00\nInitialization time,60\nmx,my,mz\n");
    for [x, y, z] in &rows {
        text.push_str(&format!("{x},{y},{z}\n"));
    }
    let file = temp_file("metadata.csv", &text);
    let run = magcal(&["fit", &file, "--format", "json"]);
    assert_same_fit(&run.json(), &reference, "metadata");
    assert_eq!(
        run.stderr,
        "magcal: note: input: 2 lines without a magnetometer reading skipped: line 1: \
         'Fs,50.00'; line 2: 'Initialization time,60'\n"
    );
    let text = magcal(&["fit", &file]);
    assert!(
        text.stdout
            .contains("\n  columns       mx,my,mz (the first three fields)\n"),
        "{}",
        text.stdout
    );
    // Wide rows after metadata: the header names the magnetometer.
    let mut wide = String::from("# a comment\nFs,50.00\nInitialization time,60\n");
    wide.push_str("t,ax,ay,az,mx,my,mz\n");
    for (i, [x, y, z]) in rows.iter().enumerate() {
        wide.push_str(&format!("{i},0.1,0.2,9.8,{x},{y},{z}\n"));
    }
    let file = temp_file("metadata_wide.csv", &wide);
    let run = magcal(&["fit", &file, "--format", "json"]);
    assert_same_fit(&run.json(), &reference, "metadata, wide");
    assert!(
        run.stderr
            .starts_with("magcal: note: columns mx,my,mz (from the header)\n"),
        "{}",
        run.stderr
    );
}

/// A metadata line of three numbers (a start date) before the metadata and
/// the header of 9-field rows: the data begin where lines of one shape
/// begin, so the date is metadata, the header names the magnetometer last,
/// and the fit is the plain file's. Taken as the first data row, the date
/// made the first three fields (a tumbling accelerometer, which lies on a
/// sphere too) the samples, with exit 0.
#[test]
fn a_date_line_before_the_header_is_metadata() {
    let (path, rows) = icm();
    let reference = magcal(&["fit", &path, "--format", "json"]).json();
    let mut text = String::from("Start,2024,05,12\nFs,50\nax,ay,az,gx,gy,gz,mx,my,mz\n");
    for [x, y, z] in &rows {
        // The accelerometer of a tumbling device: g along each row's
        // direction, a sphere of radius 9.81 about the origin.
        let n = (x * x + y * y + z * z).sqrt();
        let g = [x, y, z].map(|v| 9.81 * v / n);
        text.push_str(&format!(
            "{:.4},{:.4},{:.4},0.01,-0.02,0.00,{x},{y},{z}\n",
            g[0], g[1], g[2]
        ));
    }
    let file = temp_file("date_line.csv", &text);
    let run = magcal(&["fit", &file, "--format", "json"]);
    assert_same_fit(&run.json(), &reference, "date line");
    assert_eq!(
        run.stderr,
        "magcal: note: columns mx,my,mz (from the header)\n\
         magcal: note: input: 2 lines without a magnetometer reading skipped: line 1: \
         'Start,2024,05,12'; line 2: 'Fs,50'\n"
    );
}

/// Rows of 9 and 18 numeric fields without a header: refused without
/// `--columns`, read by field number with it, in `fit`, `apply`, `offsets`
/// and `planar` alike.
#[test]
fn columns_by_field_number_in_every_subcommand() {
    let (path, rows) = icm();
    let reference = magcal(&["fit", &path, "--format", "json"]);
    let reference_json = reference.json();
    let nine = |rows: &[[f64; 3]]| -> String {
        rows.iter()
            .map(|[x, y, z]| format!("0.12,-0.05,9.79,0.01,-0.02,0.00,{x},{y},{z}\n"))
            .collect()
    };
    let eighteen = |rows: &[[f64; 3]]| -> String {
        rows.iter()
            .map(|[x, y, z]| {
                format!(
                    "1,2,3,4,5,6,{},{},{},0.12,-0.05,9.79,0.01,-0.02,0.00,{x},{y},{z}\n",
                    x / 10.0,
                    y / 10.0,
                    z / 10.0
                )
            })
            .collect()
    };
    let file9 = temp_file("wide9.csv", nine(&rows));
    let file18 = temp_file("wide18.csv", eighteen(&rows));
    magcal(&["fit", &file9]).fails_with(
        2,
        "9 numeric columns and no header line to choose the magnetometer's x, y, z from; \
         add a header naming the columns and pass --columns X,Y,Z, or pass their field \
         numbers (from 1), e.g. --columns 7,8,9",
    );
    magcal(&["fit", &file18]).fails_with(2, "e.g. --columns 16,17,18");

    for (file, fields) in [(&file9, "7,8,9"), (&file18, "16,17,18")] {
        let run = magcal(&["fit", file, "--columns", fields, "--format", "json"]);
        assert_same_fit(&run.json(), &reference_json, fields);
        assert!(run.stderr.is_empty(), "{}", run.stderr);
        let text = magcal(&["fit", file, "--columns", fields]);
        assert!(
            text.stdout
                .contains(&format!("\n  columns       fields {fields} (--columns)\n")),
            "{}",
            text.stdout
        );
    }

    // apply: the same calibrated rows as from the plain file.
    let cal = temp_file("formats.cal.json", &reference.stdout);
    let plain = magcal(&["apply", &cal, &path]);
    assert_eq!(plain.code, 0, "{}", plain.stderr);
    let wide = magcal(&["apply", &cal, &file9, "--columns", "7,8,9"]);
    assert_eq!(wide.code, 0, "{}", wide.stderr);
    assert_eq!(wide.stdout, plain.stdout);
    // Accelerometer fields by number give headings.
    let headed = magcal(&[
        "apply",
        &cal,
        &file9,
        "--columns",
        "7,8,9",
        "--accel-columns",
        "1,2,3",
    ]);
    assert_eq!(headed.code, 0, "{}", headed.stderr);
    assert!(
        headed
            .stdout
            .starts_with("x,y,z,heading_deg,heading_smoothed_deg\n"),
        "{}",
        &headed.stdout[..80]
    );

    // offsets: the same hard iron as from the plain file.
    let plain = magcal(&["offsets", &cal, &path, "--format", "json"]);
    let wide = magcal(&[
        "offsets",
        &cal,
        &file18,
        "--columns",
        "16,17,18",
        "--format",
        "json",
    ]);
    let (plain, wide) = (plain.json(), wide.json());
    assert_eq!(plain["hard_iron"], wide["hard_iron"]);
    assert_eq!(wide["columns"], "fields 16,17,18 (--columns)");
    let text = magcal(&["offsets", &cal, &file18, "--columns", "16,17,18"]);
    assert!(
        text.stdout
            .contains("(columns fields 16,17,18 (--columns); soft iron of"),
        "{}",
        text.stdout
    );

    // planar: a turn about one axis, as 9 fields per row.
    let planar = real("planar_243.txt");
    let turns = read_xyz(&planar);
    let plain = magcal(&["planar", &planar, "--format", "json"]).json();
    let file = temp_file("planar9.csv", nine(&turns));
    let wide = magcal(&["planar", &file, "--columns", "7,8,9", "--format", "json"]).json();
    for key in ["axis", "centre", "matrix", "samples_used"] {
        assert_eq!(plain[key], wide[key], "{key}");
    }
    assert_eq!(wide["columns"], "fields 7,8,9 (--columns)");
}

/// Labelled lines through `apply`, `offsets` and `planar` (the same
/// parser), and `--columns` naming labels.
#[test]
fn labelled_lines_in_every_subcommand() {
    let (path, rows) = icm();
    let reference = magcal(&["fit", &path, "--format", "json"]);
    let cal = temp_file("formats_labelled.cal.json", &reference.stdout);
    let text: String = rows
        .iter()
        .map(|[x, y, z]| format!("Accel X: 0.1 Y: 0.2 Z: 9.8 m/s^2\nMag X: {x} Y: {y} Z: {z} uT\n"))
        .collect();
    let file = temp_file("labelled_two_sensors.txt", &text);

    let plain = magcal(&["apply", &cal, &path]);
    let labelled = magcal(&["apply", &cal, &file]);
    assert_eq!(labelled.code, 0, "{}", labelled.stderr);
    assert_eq!(labelled.stdout, plain.stdout);
    assert_eq!(
        labelled.stderr.lines().next(),
        Some("magcal: note: columns Mag X (uT),Mag Y (uT),Mag Z (uT) (labelled values)")
    );

    let plain = magcal(&["offsets", &cal, &path, "--format", "json"]).json();
    let labelled = magcal(&["offsets", &cal, &file, "--format", "json"]).json();
    assert_eq!(plain["hard_iron"], labelled["hard_iron"]);
    assert_eq!(
        labelled["columns"],
        "Mag X (uT),Mag Y (uT),Mag Z (uT) (labelled values)"
    );

    let planar = real("planar_243.txt");
    let turns: String = read_xyz(&planar)
        .iter()
        .map(|[x, y, z]| format!("mx={x} my={y} mz={z}\n"))
        .collect();
    let turns = temp_file("planar_labelled.txt", &turns);
    let plain = magcal(&["planar", &planar, "--format", "json"]).json();
    let labelled = magcal(&["planar", &turns, "--format", "json"]).json();
    assert_eq!(plain["centre"], labelled["centre"]);

    // --columns names labels: here the accelerometer's, which then is
    // calibrated (and refused: it lies still).
    let reference_json = reference.json();
    let by_name = magcal(&[
        "fit",
        &file,
        "--columns",
        "magx,magy,magz",
        "--format",
        "json",
    ]);
    assert_same_fit(&by_name.json(), &reference_json, "--columns magx,magy,magz");
    let by_label = magcal(&["fit", &file, "--columns", "Mag X,Mag Y,Mag Z"]);
    assert!(
        by_label
            .stdout
            .contains("\n  columns       Mag X (uT),Mag Y (uT),Mag Z (uT) (--columns)\n"),
        "{}",
        by_label.stdout
    );
    let accel = magcal(&["fit", &file, "--columns", "accelx,accely,accelz"]);
    assert_eq!(accel.code, 3, "{}", accel.stderr);
    magcal(&["fit", &file, "--columns", "hx,hy,hz"]).fails_with(
        2,
        "no line holds values named 'hx', 'hy', 'hz' (line 1 has: Accel X (m/s^2),",
    );
}

/// Labels that do not say which reading is the magnetometer's are refused
/// with the readings found and how to pick one.
#[test]
fn ambiguous_labelled_logs_are_refused() {
    let (_, rows) = icm();
    // Two sensors, neither named a magnetometer nor in a field's unit.
    let text: String = rows
        .iter()
        .map(|[x, y, z]| format!("A X: 0.1 Y: 0.2 Z: 9.8\nB X: {x} Y: {y} Z: {z}\n"))
        .collect();
    let file = temp_file("ambiguous_none.txt", &text);
    for format in ["text", "json"] {
        magcal(&["fit", &file, "--format", format]).fails_with(
            2,
            "labelled values, but none is the magnetometer's by its label (Mag, M, mx, ...) \
             or unit (uT, gauss, mG): found A X, A Y, A Z; B X, B Y, B Z; pass --columns with \
             the three labels to use (e.g. --columns ax,ay,az) or their numbers in the line \
             (e.g. --columns 1,2,3)",
        );
    }
    // The advice works.
    let (path, _) = icm();
    let reference = magcal(&["fit", &path, "--format", "json"]).json();
    let picked = magcal(&["fit", &file, "--columns", "bx,by,bz", "--format", "json"]);
    assert_same_fit(&picked.json(), &reference, "--columns bx,by,bz");

    // Two magnetometers: raw and calibrated under other names.
    let text: String = rows
        .iter()
        .map(|[x, y, z]| format!("Mag X: {x} Y: {y} Z: {z} uT\tmx={x} my={y} mz={z}\n"))
        .collect();
    let file = temp_file("ambiguous_two.txt", &text);
    magcal(&["fit", &file]).fails_with(
        2,
        "labelled values with 2 magnetometer readings: Mag X, Mag Y, Mag Z (uT); mx, my, \
         mz; pass --columns with the labels of the one to use",
    );
    let cal = temp_file(
        "ambiguous.cal.json",
        &magcal(&["fit", &path, "--format", "json"]).stdout,
    );
    magcal(&["apply", &cal, &file]).fails_with(2, "2 magnetometer readings");
}

/// MotionCal `Raw:` lines (magnetometer at 10 per uT) are read as before:
/// fields 7-9, the banner and `Uni:` lines skipped.
#[test]
fn motioncal_raw_lines() {
    let (path, rows) = icm();
    let reference = magcal(&["fit", &path, "--format", "json"]).json();
    let mut text = String::from("MotionCal sketch\n");
    for [x, y, z] in &rows {
        text.push_str(&format!(
            "Raw:10,-20,8192,1,2,3,{x},{y},{z}\nUni:0.1,0.2,9.8,0,0,0,1,2,3\n"
        ));
    }
    let file = temp_file("motioncal.txt", &text);
    let run = magcal(&["fit", &file, "--format", "json"]);
    assert_same_fit(&run.json(), &reference, "motioncal");
    let text = magcal(&["fit", &file]);
    assert!(
        text.stdout
            .contains("\n  columns       MotionCal Raw: lines, fields 7-9 (10 per uT)\n"),
        "{}",
        text.stdout
    );
}
